"""The demo: generate a sample DSM, filter it through qgis_process, write DTM, mask and a preview.

Usage: /usr/bin/python3 scripts/demo.py OUT_DIR   (``make demo`` runs it after the set-up)
"""
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / ".build" / "plugins"))

import numpy as np  # noqa: E402

from bare_earth.core.grid import write_array  # noqa: E402
from bare_earth.core.preview import write_preview  # noqa: E402
from bare_earth.core.synthetic import make_scene  # noqa: E402

RECOMMENDED = "dtm"  # the filter a user runs without choosing (issue 13); see the README


def qgis_process(*args):
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", QGIS_PLUGINPATH=str(ROOT / ".build" / "plugins"))
    cmd = ["qgis_process.bin", *args]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if res.returncode != 0:
        sys.stderr.write(res.stdout + res.stderr)
        raise SystemExit(f"qgis_process failed: {' '.join(cmd)}")
    return res.stdout


def main(out):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene("city", shape=(600, 800), cell_size=1.0, seed=7, nodata_holes=True)
    dsm = out / "sample_dsm.tif"
    write_array(dsm, np.where(np.isfinite(scene.dsm), scene.dsm, -9999.0), scene.geotransform, scene.epsg,
                nodata=-9999.0)
    write_array(out / "true_dtm.tif", scene.dtm, scene.geotransform, scene.epsg)
    write_array(out / "true_mask.tif", scene.mask, scene.geotransform, scene.epsg, nodata=255, mask_style=True)
    print(f"Sample DSM: {dsm} ({scene.dsm.shape[1]} x {scene.dsm.shape[0]} cells, synthetic city with truth)")
    log = qgis_process("run", f"bareearth:{RECOMMENDED}", "--",
                       f"INPUT={dsm}", f"OUTPUT_DTM={out / 'dtm.tif'}", f"OUTPUT_MASK={out / 'mask.tif'}",
                       f"OUTPUT_NDSM={out / 'ndsm.tif'}", f"OUTPUT_CONFIDENCE={out / 'confidence.tif'}")
    (out / "filter_log.txt").write_text(log)
    qgis_process("run", "bareearth:evaluate", "--", f"MASK={out / 'mask.tif'}",
                 f"REFERENCE_MASK={out / 'true_mask.tif'}", f"DTM={out / 'dtm.tif'}",
                 f"REFERENCE_DTM={out / 'true_dtm.tif'}", f"OUTPUT_JSON={out / 'evaluation.json'}",
                 f"OUTPUT_HTML={out / 'evaluation.html'}")
    preview = write_preview(out / "preview.png", str(dsm), str(out / "dtm.tif"), str(out / "mask.tif"))
    figures = json.loads((out / "evaluation.json").read_text())
    print("Wrote:")
    for name in ("dtm.tif", "mask.tif", "mask.qml", "ndsm.tif", "confidence.tif", "preview.png", "evaluation.html",
                 "evaluation.json"):
        print(f"  {out / name}")
    for k, v in figures.get("results", figures).items():
        if isinstance(v, dict):
            print(f"{k}: " + ", ".join(f"{a} {_figure(a, b)}" for a, b in v.items() if isinstance(b, (int, float))))
    return preview


def _figure(name, value):
    """A figure as people read it: counts as integers, percentages with %, metres with m."""
    if isinstance(value, int) or name in ("a", "b", "c", "d", "n") or name.startswith("n_") or name.endswith("_n"):
        return f"{int(value):,}"
    if name in ("type1", "type2", "total", "kappa"):
        return f"{value:.2f} %"
    return f"{value:.3f} m"


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ROOT / "out" / "demo")
