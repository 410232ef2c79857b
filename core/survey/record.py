"""The run record ``run.json`` of a survey: parameters used, per-tile status, timings,
workers. Rewritten atomically (temporary file, flush to disk, rename) every time a tile is
recorded, so it always parses and never names a tile whose outputs are not complete.
"""
import json
import os
import time

from ...meta import VERSION

#: The record's format tag.
FORMAT = "bare-earth survey run 1"
#: The record's file name in the output folder.
NAME = "run.json"


def record_path(out_dir):
    return os.path.join(str(out_dir), NAME)


def load_record(out_dir):
    """The record in ``out_dir``, or None when there is none.

    Raises
    ------
    ValueError
        When ``run.json`` exists but is not a Bare Earth survey record.
    """
    path = record_path(out_dir)
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as f:
            rec = json.load(f)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} is not readable ({exc}): delete it to start the survey again.") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT:
        raise ValueError(f"{path} is not a Bare Earth survey record: choose another output folder.")
    return rec


def save_record(out_dir, rec):
    """Write ``rec`` as ``run.json`` atomically (temporary sibling, fsync, rename)."""
    path = record_path(out_dir)
    tmp = f"{path}.partial-{os.getpid()}"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(rec, f, indent=1, default=_plain)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _plain(v):
    """numpy scalars and tuples as JSON."""
    if hasattr(v, "item"):
        return v.item()
    if isinstance(v, (set, frozenset)):
        return sorted(v)
    raise TypeError(f"{type(v).__name__} is not JSON serialisable")


def new_record(arguments):
    """An empty record for a run of ``arguments`` (method, user parameters, tiles), stamped with the
    plugin's version (:func:`other_version` refuses to resume it with another)."""
    return {"format": FORMAT, "arguments": arguments, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "plugin_version": VERSION, "tiles": {}, "runs": []}


def other_version(rec):
    """The plugin version that made ``rec`` when it is not this one, else None (also for a record
    that does not say, made before records said it). Tiles filtered by two versions do not join
    seamlessly (their rules and the parameters they derive may differ), so a survey is finished by the
    version that began it."""
    made = (rec or {}).get("plugin_version")
    return None if made is None or str(made) == VERSION else str(made)


def same_arguments(rec, arguments):
    """True when ``rec`` was made by a run of the same method, parameters and tiles."""
    return json.loads(json.dumps(rec.get("arguments"), default=_plain)) == \
        json.loads(json.dumps(arguments, default=_plain))


def tiles_with_status(rec, status="done"):
    """``{name: entry}`` of the tiles of the record with ``status`` ("pending", "done" or
    "failed")."""
    return {k: v for k, v in (rec or {}).get("tiles", {}).items() if v.get("status") == status}


def done_tiles(rec, out_dir):
    """Names of the tiles recorded done whose output files all exist (as files)."""
    out = set()
    for name, t in (rec or {}).get("tiles", {}).items():
        if t.get("status") == "done" and all(os.path.isfile(os.path.join(str(out_dir), f))
                                             for f in t.get("files", ())):
            out.add(name)
    return out


def input_stamps(paths):
    """``{path: [size in bytes, modification time in ns]}`` of the input tiles: what a rerun
    compares to tell whether a tile changed since its outputs were recorded."""
    out = {}
    for p in paths:
        st = os.stat(p)
        out[str(p)] = [int(st.st_size), int(st.st_mtime_ns)]
    return out


def changed_inputs(rec, paths):
    """The tiles of ``paths`` whose size or modification time differ from those recorded in
    ``rec`` (none when the record holds no stamps: a record of an older version)."""
    stamps = (rec or {}).get("input_stamps")
    if not stamps:
        return []
    now = input_stamps(paths)
    return [p for p in paths if str(p) in stamps and list(stamps[str(p)]) != now[str(p)]]
