"""Shared parts of the benchmark scripts: make ``import bare_earth`` work from a clone, read a
benchmark's JSON-lines log, and write a table a benchmark owns into README.md between its markers."""
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / ".build" / "plugins"


def setup_path():
    link = PLUGINS / "bare_earth"
    if not link.exists():
        PLUGINS.mkdir(parents=True, exist_ok=True)
        try:
            link.symlink_to(Path("..") / "..", target_is_directory=True)
        except FileExistsError:
            pass
    if str(PLUGINS) not in sys.path:
        sys.path.insert(0, str(PLUGINS))


def data_dir(arg=None):
    return Path(arg or os.environ.get("BARE_EARTH_DATA", ROOT.parent / "shared" / "data"))


def read_log(path):
    """The records of a benchmark's JSON-lines log (``benchmarks/results/*.jsonl``), oldest first."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no benchmark log {path}: run the benchmark without --from-log first "
                                "(it appends its figures there), or pass the log with --out")
    return [json.loads(ln) for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]


def last_record(path):
    """The newest record of a benchmark's JSON-lines log (what ``--from-log`` renders)."""
    records = read_log(path)
    if not records:
        raise ValueError(f"the benchmark log {path} holds no record: run the benchmark without --from-log first")
    return records[-1]


def replace_block(path, begin, end, text, missing=None):
    """Put ``text`` between the marker comments ``begin`` and ``end`` of the file at ``path`` (a table of
    README.md that a benchmark writes), leaving the rest of the file as it is.

    ``text`` ends with a newline; the markers stay on lines of their own. Without the markers,
    ``missing(src, block)`` returns the file with the block (markers and text) placed; without
    ``missing`` that is a ValueError naming the markers to add.
    """
    path = Path(path)
    src = path.read_text(encoding="utf-8")
    block = f"{begin}\n{text}{end}"
    if begin in src and end in src.split(begin, 1)[1]:
        pre, rest = src.split(begin, 1)
        src = pre + block + rest.split(end, 1)[1]
    elif missing is not None:
        src = missing(src, block)
    else:
        raise ValueError(f"{path} has no block between {begin!r} and {end!r}: add the two markers, each on a "
                         "line of its own, where the table belongs")
    path.write_text(src, encoding="utf-8")
