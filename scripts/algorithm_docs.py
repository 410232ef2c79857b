"""Print the README's algorithm reference (Markdown) from the core's method specs and the
dialog labels of the QGIS layer (``algorithms/labels.py``, which imports no QGIS).

Usage: /usr/bin/python3 scripts/algorithm_docs.py [--write README.md]
With --write, replaces the text between the markers in README.md.
"""
import html
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / ".build" / "plugins"))

from bare_earth.algorithms.labels import extra_label, is_advanced, param_label  # noqa: E402
from bare_earth.core.codes import MASK_CODES  # noqa: E402
from bare_earth.core.grid import OUTPUT_FORMATS  # noqa: E402
from bare_earth.core.methods import available_methods  # noqa: E402

BEGIN, END = "<!-- algorithms:begin -->", "<!-- algorithms:end -->"


def strip_html(s):
    s = re.sub(r"</p>\s*<p>", "\n\n", s)
    return html.unescape(re.sub(r"<[^>]+>", "", s)).strip()


def plugin_methods():
    """Method names that have an algorithm class in algorithms/filters.py (no QGIS import)."""
    text = (ROOT / "algorithms" / "filters.py").read_text()
    return re.findall(r'METHOD_NAME\s*=\s*"([^"]+)"', text)


def point_methods():
    """Method names whose algorithm class also takes points (``PointsInputMixin``)."""
    text = (ROOT / "algorithms" / "filters.py").read_text()
    return re.findall(r'class \w+\(PointsInputMixin[^)]*\):.*?METHOD_NAME\s*=\s*"([^"]+)"', text, re.S)


#: Inputs a method's algorithm adds to its parameters (rows after ``BAND``).
LAYER_ROWS = {
    "dtm": [
        "| `OBJECT_AREAS` (Object areas) | optional | polygons (e.g. building footprints) that are objects "
        "whatever the filters say; the ground under them is interpolated |",
        "| `GROUND_AREAS` (Ground areas) | optional | polygons or points of known bare ground (a car park "
        "under trees, survey points): ground whatever the filters say |",
        "| `BREAKLINES` (Break lines) | optional | lines along crests, toes and terrace edges: no comparison "
        "crosses them (as in RASCOR), and near them RASCOR's decision stands alone |",
    ],
    "rascor": [
        "| `BREAKLINES` (Break lines) | optional | lines (any CRS) along crests, toes, cuts and embankment "
        "shoulders: no comparison crosses them |",
        "| `SPECIAL_AREAS` (Special areas) | optional | polygons (any CRS) inside which only the local filters "
        "(steps 3 and 7) run, e.g. cars and bushes on a dam's slope |",
    ],
}
#: The point-cloud inputs of the algorithms that take points (``PointsInputMixin``).
POINTS_ROWS = [
    "| `INPUT_POINTS`, `POINTS_CRS`, `CELL_SIZE_M` | optional | a point cloud (text/CSV or LAS/LAZ) filtered "
    "instead of `INPUT`: rasterised (cell size empty: from the point density), filtered and classified in one "
    "run; its CRS when the file has none (*Point clouds* below) |",
    "| `THRESHOLD_M`, `SLOPE_FACTOR` | 0.5, 1.25 | a point is ground when \\|z - DTM\\| <= threshold + factor x "
    "local DTM slope (advanced) |",
    "| `OTHER_TILES`, `OUTPUT_POINTS` | optional | adjoining point tiles filtered as one block (advanced); the "
    "classified points (text with a class column, or LAS with ASPRS codes) |",
]
#: What a side product holds, where more than its name says.
EXTRA_MEANING = {
    "confidence": "UInt8 0-100, 255 nodata: how sure each cell's class is (styled red to green)",
}


def render():
    out = []
    methods = available_methods()
    for name in plugin_methods():
        if name not in methods:
            continue
        m = methods[name]
        out.append(f"### `bareearth:{name}`: {m.title}\n")
        out.append(strip_html(m.description) + "\n")
        out.append("| parameter (dialog label) | default | meaning |\n|---|---|---|")
        out.append("| `INPUT` (Input DSM) | | single-band DSM raster |")
        out.append("| `BAND` (Height band) | 1 | height band, when the raster has several |")
        out.extend(LAYER_ROWS.get(name, []))
        for p in m.params:
            d = "from the data" if p.default is None else f"`{p.default}`"
            adv = " (advanced)" if is_advanced(name, p) else ""
            label = param_label(name, p).replace(" [empty: from the data]", "")
            out.append(f"| `{p.name.upper()}` ({label}) | {d} | {p.help}{adv} |")
        out.append("| `BLOCK_SIZE`, `THREADS`, `PROCESSES` | 0, 0, 1 | block edge in cells (0 automatic, else at "
                   "least 64), threads (0: one per core) and worker processes running blocks (advanced) |")
        out.append("| `CREATE_OPTIONS`, `COG` | empty, no | GeoTIFF creation options (`COMPRESS=ZSTD\\|PREDICTOR=2`) "
                   "and cloud-optimised GeoTIFF outputs (advanced) |")
        out.append("| `OUTPUT_DTM`, `OUTPUT_MASK` | | Float32 DTM, UInt8 mask (" +
                   ", ".join(f"{k} {v}" for k, v in MASK_CODES.items()) + ") |")
        out.append("| `OUTPUT_NDSM` | optional | DSM minus DTM |")
        for k in m.extras:
            meaning = EXTRA_MEANING.get(k, f"per-cell side product `{k}`")
            out.append(f"| `OUTPUT_{k.upper()}` ({extra_label(k)}) | optional | {meaning} |")
        if name in point_methods():
            out.extend(POINTS_ROWS)
        out.append("")
        out.append("Outputs are written in the format their extension names: "
                   + ", ".join(f"`{e}`" for e in OUTPUT_FORMATS) + ".\n")
    return "\n".join(out)


if __name__ == "__main__":
    text = render()
    if len(sys.argv) > 2 and sys.argv[1] == "--write":
        p = Path(sys.argv[2])
        s = p.read_text()
        a, b = s.index(BEGIN) + len(BEGIN), s.index(END)
        p.write_text(s[:a] + "\n" + text + "\n" + s[b:])
    else:
        print(text)
