"""A whole survey through one filter: index, parameters once, tiles on Dask, mosaics.

::

    tiles --index_tiles--> checked grid --survey.vrt--> sample --resolve--> params, halo
          --Dask: run_tile(tile + halo from survey.vrt)--> <tile>_dtm.tif, <tile>_mask.tif
          --as each finishes--> run.json --when every tile is done--> dtm.vrt, mask.vrt

The mosaics exist only over a complete survey: a run that leaves a tile failed, pending
(cancelled) or unstarted (killed) leaves no ``dtm.vrt`` / ``mask.vrt`` (those of an earlier
complete run are removed before any tile is redone), ``run.json`` says ``"complete": false``
and the log names the tiles missing and how to finish (the same command again).
"""
import math
import os
import re
import tempfile
import time

import numpy as np

from .. import grid, pipeline
from ..common import Cancelled, sub_progress, without_far_heights
from ..methods import get_method
from . import engine, io, plan, record
from .index import index_tiles
from .task import TileJob, output_names, run_tile

#: The survey VRT the tasks read their windows from (in the output folder, which every
#: worker sees).
SURVEY_VRT = "survey.vrt"
#: Seconds between two rewrites of run.json while tiles finish (it is rewritten at the
#: end in any case; a tile finished in the last interval of a killed run is redone).
RECORD_INTERVAL = 1.0
#: The share of the progress bar the parameters' derivation takes (the method's estimates on
#: a sample of at most 4096 x 4096 cells: up to a minute), before the tiles share the rest.
DERIVE_SHARE = 0.1
#: The mosaics written once every tile is done.
MOSAICS = ("dtm.vrt", "mask.vrt")
#: Names of the temporary files of io.write_cog, io.build_vrt and record.save_record.
PARTIAL = re.compile(r"\.partial-[0-9a-f]+(\.[A-Za-z]+)*$")


def _param_value(param, text):
    """A parameter's text as its Param kind (float, int, bool, enum)."""
    if param.kind in ("float", "int"):
        try:
            value = float(text)
            if param.kind == "int":          # 2 or 2.0, as the dialog's whole numbers take them
                if not value.is_integer():
                    raise ValueError
                value = int(value)
            return value
        except (ValueError, OverflowError):
            raise ValueError(f"{param.name} takes {'a number' if param.kind == 'float' else 'a whole number'}; "
                             f"got {text!r}.") from None
    if param.kind == "bool":
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"{param.name} takes true or false; got {text!r}.")
    if param.options:
        match = [o for o in param.options if o.lower() == text.lower()]   # 'Flat' as the dialog shows it
        if not match:
            raise ValueError(f"{param.name} takes one of {', '.join(param.options)}; got {text!r}.")
        return match[0]
    return text


def parse_params(method, items):
    """``KEY=VALUE`` strings (or one string of them separated by spaces, commas, semicolons or
    new lines) -> the keyword arguments of ``method`` (a Method or its id), each converted
    to its Param kind; an empty value means "derived from the data". ValueError names a
    bad one, or one given twice (in any case of its key)."""
    if isinstance(method, str):
        method = get_method(method)
    if isinstance(items, str):
        spaced = re.search(r"\S[ \t]+=|=[ \t]+[^\s=,;]+(?=[\s,;]|$)", items)    # 'dh_m = 1', 'dh_m= 1'
        if spaced:
            raise ValueError(f"parameters {items!r}: write each KEY=VALUE without spaces around '=' (spaces "
                             "separate parameters).")
        items = [s for s in re.split(r"[\s,;]+", items) if s]
    known = {p.name: p for p in method.params}
    out, given = {}, {}
    previous = None
    for item in items or ():
        key, sep, text = item.partition("=")
        key = key.strip().lower()
        if not sep or not key:
            if previous is not None and re.fullmatch(r"[^=]+=-?\d+", previous) and item.isdigit():  # 0,1
                raise ValueError(f"parameter '{previous},{item}': write numbers with a decimal point "
                                 f"({previous.partition('=')[2]}.{item}); commas separate parameters.")
            raise ValueError(f"parameter {item!r}: write KEY=VALUE.")
        previous = item
        if key not in known:
            raise ValueError(f"parameter {key}: method {method.name!r} takes " + (
                f"{', '.join(sorted(known))}." if known else "no parameter (it derives every value from the data): "
                "give none, or choose a method that takes it."))
        if key in given:    # the last would win without a word: which one was meant?
            raise ValueError(f"parameter {key} is given twice ({given[key]!r} and {item!r}): give it once.")
        given[key] = item
        try:
            out[key] = None if text.strip() == "" else _param_value(known[key], text.strip())
        except ValueError as exc:
            raise ValueError(f"parameter {item!r}: {exc}") from None
    method.check_given(out)     # out of range, an even window: refused now, not once the cluster runs
    return out


def read_sample(index, info, max_cells=None):
    """The surface the survey's parameters are derived from, and what it is.

    The whole survey when small (``max_cells``, default :data:`plan.SAMPLE_CELLS`), else
    central crops of tiles spread over it, laid side by side with nodata between them
    (:func:`plan.sample_layout`; each crop's empty cells enclosed by data filled as the filters
    see them, :func:`pipeline.fill_empty_cells`). Nodata cells are NaN (the estimates never see them), and a
    chosen tile whose crop holds no data at all (sea, a hole in the survey) gives way to the
    nearest tile whose crop does, so the sample holds the survey's data wherever it lies.
    """
    layout = plan.sample_layout(index.tiles, index.shape[0] * index.shape[1], max_cells or plan.SAMPLE_CELLS)
    if layout is None:
        return info.read(), f"the whole survey ({index.shape[1]} x {index.shape[0]} cells)"
    parts, shape = layout
    side = max(max(w[1] - w[0], w[3] - w[2]) for _t, w, _p in parts)
    z = np.full(shape, np.nan, np.float32)
    used, empty, names, replaced = {t.name for t, _w, _p in parts}, set(), [], 0
    for tile, _window, (r, c) in parts:
        for cand in plan.nearest_tiles([t for t in index.tiles if t.name not in empty], tile):
            if cand is not tile and cand.name in used:
                continue
            r0, r1, c0, c1 = plan.central_crop(cand, side)
            crop = info.read((r0, r1, c0, c1))
            if np.isfinite(crop).any():
                # its empty cells filled as a filter sees them; the gutters between the crops stay nodata
                z[r:r + r1 - r0, c:c + c1 - c0] = pipeline.fill_empty_cells(crop, info.cell_size_m)[0]
                used.add(cand.name)
                names.append(cand.name)
                replaced += cand is not tile
                break
            empty.add(cand.name)
    where = (f"central crops of up to {side} x {side} cells of {len(names)} tiles spread over the survey "
             f"({', '.join(names) or 'none with data'})")
    if replaced:
        where += f"; {replaced} chosen tile(s) without data at their centre replaced by the nearest with data"
    return z, where


def check_survey_relief(index, sample=1_000_000):
    """:func:`.pipeline.check_relief` of a survey that is its own parameter sample (at most
    :data:`.plan.SAMPLE_CELLS`: the cells :func:`run_survey` checks), read every ``step``-th cell through a
    VRT in a temporary folder (at most about ``sample`` cells), for the checks before a run (the algorithm's
    dialog). ValueError naming the survey as the run does; the warning or None; None for a larger survey
    (the run checks its sample of crops) or one without data there."""
    rows, cols = index.shape
    if rows * cols > plan.SAMPLE_CELLS:
        return None
    step = max(1, int(math.ceil(math.sqrt(rows * cols / float(sample)))))
    with tempfile.TemporaryDirectory(prefix="bare-earth-check-") as folder:
        vrt = io.build_vrt(os.path.join(folder, SURVEY_VRT), [t.path for t in index.tiles], index.vrt_nodata,
                           index.tiles[0].unit_type)
        info = grid.open_dsm(vrt)
        z, _ = without_far_heights(info.surface(info.read_stored(step=step), None, step))
        cell = tuple(float(v) for v in info.cell_size_m)
        info = None          # its dataset closed before the folder goes
    if not np.isfinite(z).any():
        return None
    try:
        return pipeline.check_relief(z, cell, shape=(rows, cols))
    except ValueError as e:
        raise ValueError(f"{e} (in the whole survey ({cols} x {rows} cells))") from None


def run_survey(method, inputs, out_dir, params=None, *, workers=0, scheduler=None, progress=None, log=None):
    """Filter a survey of tiles into one DTM and one mask per tile, seamlessly, on Dask.

    Parameters
    ----------
    method : str
        A registered method id (``methods.available_methods``).
    inputs : str or list of str
        The tiles: several rasters, one VRT over them, or one folder of rasters.
    out_dir : str
        Output folder: ``<tile>_dtm.tif`` and ``<tile>_mask.tif`` per tile (COG, the
        tile's grid), ``dtm.vrt``, ``mask.vrt`` (+ ``mask.qml``), ``run.json``, and the
        ``survey.vrt`` the tasks read. Every worker must see it at this path.
    params : dict, optional
        The method's parameters; missing or None ones are derived once for the whole
        survey from a sample spread over its tiles.
    workers : int
        Local worker processes (0: one per core); ignored with ``scheduler``.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``).
    progress : callable, optional
        ``progress(fraction)``: the parameters' derivation its first :data:`DERIVE_SHARE`
        (when they are derived), then the fraction of tiles finished; may raise
        :class:`Cancelled`: during the derivation nothing is left (the output folder as it
        was); later no new tile is handed out, the pending ones are cancelled, the finished
        ones stay recorded, and Cancelled propagates.
    log : callable, optional
        ``log(str)`` for the parameters used, the sample and each finished tile.

    Returns
    -------
    dict
        The run record (as in ``run.json``) with ``"this_run"``: this run's summary;
        ``"complete"`` is True only when every tile is done (then ``dtm.vrt`` and
        ``mask.vrt`` exist), else ``"missing_tiles"`` names the others.

    Raises
    ------
    ValueError
        Before any work: unknown method or parameters, missing tiles, tiles of mixed CRS
        or cell size, overlapping tiles, an output folder holding a run of other
        arguments, or one begun by another plugin version (:func:`.record.other_version`) with tiles
        left to do. ImportError when Dask is missing.
    """
    log = log or (lambda s: None)
    meth = get_method(method)
    engine.require_dask()
    engine.check_scheduler_address(scheduler)
    if not scheduler:
        engine.check_workers(workers)
    index = index_tiles(inputs)
    check_output_folder(index, out_dir, inputs)
    out_dir = os.path.abspath(str(out_dir))
    user = {k: v for k, v in (params or {}).items() if v is not None}
    arguments = {"method": meth.name, "params": user, "tiles": [t.path for t in index.tiles]}
    rec = record.load_record(out_dir) if os.path.isdir(out_dir) else None
    if rec is not None and not record.same_arguments(rec, arguments):
        a = rec.get("arguments", {})
        raise ValueError(f"{out_dir} holds a run of other arguments (method {a.get('method')!r}, parameters "
                         f"{a.get('params')}, {len(a.get('tiles', []))} tiles): choose another output folder, or "
                         "delete its run.json to start again there.")
    changed = record.changed_inputs(rec, arguments["tiles"]) if rec is not None else []
    if changed:
        raise ValueError(f"{len(changed)} tile(s) changed since the run recorded in {record.record_path(out_dir)} "
                         f"(size or modification time): {', '.join(os.path.basename(p) for p in changed[:5])}"
                         + (f" and {len(changed) - 5} more" if len(changed) > 5 else "") + ". Their outputs, their "
                         "neighbours' (the halo) and the parameters derived from the survey may be stale: choose "
                         "another output folder, or delete its run.json to start again there.")
    kept = record.done_tiles(rec, out_dir)
    made_by = record.other_version(rec)
    if made_by is not None and len(kept) < len(index.tiles):    # tiles of two versions: seams, stale parameters
        raise ValueError(f"{record.record_path(out_dir)} records a run made by Bare Earth {made_by}, and this is "
                         f"{record.VERSION}: finishing it would join tiles filtered by two versions (their rules "
                         "and derived parameters may differ: seams). Choose another output folder, or delete its "
                         "run.json to start again there.")
    for t in index.tiles:   # an output a task could not replace: refused now, not as a failed tile at the end
        for name in output_names(t.name) if t.name not in kept else ():
            grid.check_replaceable(os.path.join(out_dir, name))
            grid.check_side_files(os.path.join(out_dir, name))       # its .aux.xml
    created = not os.path.isdir(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    _remove_partials(out_dir, log)
    vrt = io.build_vrt(os.path.join(out_dir, SURVEY_VRT), [t.path for t in index.tiles], index.vrt_nodata,
                       index.tiles[0].unit_type)
    info = grid.open_dsm(vrt)
    cell = tuple(float(v) for v in info.cell_size_m)
    if rec is None:
        rec = record.new_record(arguments)
        rec["input_stamps"] = record.input_stamps(arguments["tiles"])
    share = DERIVE_SHARE if "params" not in rec else 0.0
    if "params" not in rec:
        t0 = time.perf_counter()
        zs, where = read_sample(index, info)
        if not np.isfinite(zs).any():
            os.remove(vrt)
            if created:
                os.rmdir(out_dir)
            raise ValueError(f"the survey holds no data in {where}: every cell is nodata there, so nothing can be "
                             "filtered and no parameter derived. Check the tiles' nodata value (gdalinfo), or give "
                             "the tiles that hold data.")
        try:      # heights far steeper than any terrain: a cell size in mm or cm read as m
            steep = pipeline.check_relief(zs, cell)
        except ValueError as e:
            os.remove(vrt)
            if created:
                os.rmdir(out_dir)
            raise ValueError(f"{e} (in {where})") from None
        for suspect in (grid.undeclared_nodata_warning(info, zs), grid.nodata_among_heights_warning(info, zs),
                        steep):
            if suspect:
                log(f"Warning: {suspect.replace('<file>', '<tile>')} (in {where})")
        try:      # the bar moves while they are derived (a minute on 16 Mcells), and a cancel stops it
            resolved = pipeline.resolve_params(meth, zs, cell, user, progress=sub_progress(progress, 0.0, share),
                                               fill_empty=zs.shape == tuple(index.shape))
        except Cancelled:
            os.remove(vrt)
            if created:
                os.rmdir(out_dir)
            raise
        if zs.shape != tuple(index.shape):      # a sample: heights of the whole survey beyond it
            resolved = pipeline.widen_params(meth, info, resolved, user, log)
        del zs
        rec.update({"method": meth.name, "params": resolved, "sample": where,
                    "resolve_seconds": round(time.perf_counter() - t0, 3)})
    resolved = rec["params"]
    halo = pipeline.window_halo(meth, resolved, cell)   # the method's reach and the empty cells' fill
    align = plan.alignment(halo)
    rec.update({"halo_cells": halo, "align_cells": align,
                "survey": {"tiles": len(index.tiles), "cells": index.cells, "shape": list(index.shape),
                           "geotransform": list(index.geotransform), "crs": io.crs_label(index.crs_wkt),
                           "cell_size_m": list(cell), "vrt": SURVEY_VRT}})
    log(f"Survey: {len(index.tiles)} tiles, {index.cells / 1e6:.1f} Mcells on a {index.shape[1]} x "
        f"{index.shape[0]} grid of {cell[0]:.4g} x {cell[1]:.4g} m ({rec['survey']['crs']}).")
    for note in sorted({grid.nodata_not_kept(t.nodata, t.scale, t.offset, t.dtype) for t in index.tiles} - {None}):
        log(note)
    undeclared = [t.name for t in index.tiles if t.nodata is None]
    if undeclared and index.vrt_nodata not in (None, "nan"):
        log(f"Warning: {len(undeclared)} tile(s) declare no nodata value ({', '.join(undeclared[:5])}"
            + (" ..." if len(undeclared) > 5 else "") + f"): their cells of {index.vrt_nodata:g} (the value the "
            "survey's gaps between tiles take) are read as nodata. If that is a height, declare another nodata "
            "value on the tiles (gdal_edit.py -a_nodata).")
    log(f"Parameters derived once for the survey from {rec['sample']}:")
    for k, v in resolved.items():
        log(f"  {k} = {v}")
    log(f"Halo: {halo} cells read from the neighbouring tiles around each tile (windows aligned on {align}).")
    if not scheduler:
        windows = [plan.tile_window(t.window, index.shape, halo, align)[0] for t in index.tiles]
        warning = engine.memory_warning(workers, max((w[1] - w[0]) * (w[3] - w[2]) for w in windows))
        if warning:
            log("Warning: " + warning)
    done = record.done_tiles(rec, out_dir)
    todo = [t for t in index.tiles if t.name not in done]
    for t in todo:
        rec["tiles"][t.name] = {"status": "pending", "input": t.path}
    if todo:   # mosaics of an earlier run no longer stand for the survey: gone before any tile runs
        _remove_mosaics(rec, out_dir)
    if done:
        log(f"{len(done)} tile(s) already done (recorded in run.json); {len(todo)} to do.")
    record.save_record(out_dir, rec)
    job = TileJob(meth.name, resolved, vrt, out_dir, halo, align, tuple(index.shape), cell,
                  index.crs_wkt)
    this = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "scheduler": scheduler or "local",
            "tiles_to_do": len(todo), "tiles_done": 0, "failed": {}}
    rec["runs"].append(this)
    t_run = time.perf_counter()
    last_save = [time.perf_counter()]
    try:
        if todo:
            _run_tiles(rec, this, job, todo, out_dir, workers, scheduler, sub_progress(progress, share, 1.0), log,
                       last_save)
    except Cancelled:
        this["cancelled"] = True
        log("Cancelled: no new tile handed out; the finished tiles are recorded, a rerun does the rest.")
        raise
    finally:
        this["wall_s"] = round(time.perf_counter() - t_run, 3)
        record.save_record(out_dir, rec)
    _write_mosaics(index, rec, out_dir, log)
    record.save_record(out_dir, rec)
    rec["this_run"] = this
    return rec


def check_output_folder(index, out_dir, inputs=None):
    """ValueError, before any work, when ``out_dir`` cannot receive the survey's outputs: empty
    (the current folder), an existing file, the folder of one of the tiles (the outputs would lie among the tiles,
    and the folder given again as the input would take them for tiles), or a folder where an
    output would replace one of ``inputs`` (a VRT over the tiles named ``dtm.vrt``,
    ``mask.vrt`` or ``survey.vrt``, or another name of one: a link, another case where the folder
    ignores it), or one holding a folder named as a file the survey writes (``survey.vrt``,
    ``dtm.vrt``, ``mask.vrt``, ``mask.qml``, ``run.json``), or a folder that ignores case
    (:func:`.grid.folder_ignores_case`) for tiles whose names differ only in case, or a folder that
    takes no new file (read-only; a new one: the folder it is created in, or a file on its path), or one holding a
    file the survey writes read-only."""
    if not str(out_dir).strip():     # an unset variable in a script: the outputs went to the current folder
        raise ValueError(f"the output folder is empty: give the folder the outputs go to (an empty one would be "
                         f"the current folder, {os.getcwd()!r}).")
    out_dir = os.path.realpath(os.path.abspath(str(out_dir)))
    given = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs or [])
    own = [SURVEY_VRT, "dtm.vrt", "mask.vrt", "mask.qml", record.NAME]
    names = own + [n for t in index.tiles for n in output_names(t.name)]
    outputs = {grid.file_identity(os.path.join(out_dir, n)) for n in names}
    hit = [str(p) for p in given if grid.file_identity(p) in outputs]   # another name of it too (a link, a case)
    if hit:
        raise ValueError(f"an output in {out_dir!r} would replace the input {hit[0]!r}: choose another output "
                         "folder (or rename the input).")
    grid.check_output_dir(out_dir)   # a folder taking files (read-only: a traceback renaming survey.vrt's work file)
    folders = [n for n in own if os.path.isdir(os.path.join(out_dir, n))]
    if folders:      # found once every tile was done (a traceback), or at the start (survey.vrt)
        raise ValueError(f"the output folder {out_dir!r} holds a folder named {folders[0]}, a file the survey "
                         "writes: move or rename that folder, or choose another output folder.")
    for name in own:  # read-only: a PermissionError traceback once every tile was done (mask.qml), or at the start
        try:
            grid.check_replaceable(os.path.join(out_dir, name))
        except ValueError:
            raise ValueError(f"the output folder {out_dir!r} holds {name}, a file the survey writes, read-only (or no "
                             "regular file): make it writable, delete it, or choose another output folder.") from None
    if grid.folder_ignores_case(out_dir):      # T1.tif and t1.tif: one T1_dtm.tif there
        first, same = {}, []
        for t in index.tiles:
            other = first.setdefault(t.name.casefold(), t)
            if other is not t:
                same.append((other, t))
        if same:
            a, b = same[0]
            raise ValueError(f"tiles {a.path!r} and {b.path!r} have names differing only in case ({a.name}, {b.name}), "
                             f"but the output folder {out_dir!r} ignores case: their outputs would be one file. "
                             "Rename one of them, or choose an output folder on a file system that counts case.")
    inside = [t.path for t in index.tiles if grid.file_identity(os.path.dirname(t.path)) == grid.file_identity(out_dir)]
    if inside:
        raise ValueError(f"the output folder {out_dir!r} holds the tiles ({os.path.basename(inside[0])}"
                         + (f" and {len(inside) - 1} more" if len(inside) > 1 else "") + "): the outputs would be "
                         "mixed with them, and the folder given again as the input would take the outputs for "
                         "tiles. Choose another output folder.")


def _remove_mosaics(rec, out_dir):
    """Remove ``dtm.vrt`` and ``mask.vrt`` and mark the record incomplete."""
    for name in MOSAICS:
        path = os.path.join(out_dir, name)
        if os.path.lexists(path):
            os.remove(path)
    rec.pop("mosaics", None)
    rec["complete"] = False


def _remove_partials(out_dir, log):
    """Remove the temporary files a killed run left in ``out_dir`` (``*.partial-*``: tiles,
    VRTs and run.json being written when it died). Called before any task starts."""
    stale = [f for f in os.listdir(out_dir) if PARTIAL.search(f)]
    for f in stale:
        try:
            os.remove(os.path.join(out_dir, f))
        except OSError:
            pass
    if stale:
        log(f"Removed {len(stale)} unfinished file(s) of an earlier run.")


def _run_tiles(rec, this, job, todo, out_dir, workers, scheduler, progress, log, last_save):
    """Hand the tiles to the cluster and record each as it finishes."""
    client, cluster = engine.start_client(workers, scheduler, log)
    try:
        this["workers"] = engine.worker_summary(client)
        this["scheduler_address"] = client.scheduler.address
        t_start = time.perf_counter()

        def done(tile, entry):
            rec["tiles"][tile.name] = dict(entry, input=tile.path)
            this["tiles_done"] += 1
            log(f"{tile.name}: done in {entry['seconds']:.2f} s on {entry['worker']} "
                f"({entry['counts']['object']} object cells)")
            if entry.get("moved_off_nodata"):
                nodata = grid.float_output_nodata(tile.nodata, tile.scale, tile.offset, tile.dtype)
                log(f"Warning: {tile.name}: " + grid.moved_off_nodata_message(entry["moved_off_nodata"], nodata))
            if time.perf_counter() - last_save[0] >= RECORD_INTERVAL:
                record.save_record(out_dir, rec)
                last_save[0] = time.perf_counter()

        def failed(tile, exc):
            this["failed"][tile.name] = f"{type(exc).__name__}: {exc}"
            rec["tiles"][tile.name] = {"status": "failed", "input": tile.path, "error": this["failed"][tile.name]}
            for name in output_names(tile.name):     # one file of the pair may be in place: never half a tile
                path = os.path.join(out_dir, name)
                if os.path.isfile(path):
                    try:
                        os.remove(path)
                    except OSError as exc:
                        log(f"Warning: {tile.name}: cannot remove {name} ({exc.strerror}): delete it before a rerun.")
            log(f"{tile.name}: FAILED ({type(exc).__name__}: {exc}); a rerun retries it.")

        engine.run_tasks(client, run_tile, job, todo, done, failed, progress)
        wall = time.perf_counter() - t_start
        this["tiles_wall_s"] = round(wall, 3)
        done_now = record.tiles_with_status(rec, "done")
        cells = sum(t.cells for t in todo if t.name in done_now)
        this["mcells_per_s"] = round(cells / 1e6 / wall, 3) if wall > 0 else None
        this["workers"] = engine.worker_summary(client) or this["workers"]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if this["failed"]:
        log(f"{len(this['failed'])} tile(s) failed: {', '.join(sorted(this['failed']))}.")


def _write_mosaics(index, rec, out_dir, log):
    """dtm.vrt and mask.vrt over the tiles (mask.qml beside the mask) when every tile is done;
    else none (a mosaic with holes would look like the survey's result), the record marked
    incomplete and the log naming the tiles missing and how to finish."""
    done = record.tiles_with_status(rec, "done")
    missing = [t for t in index.tiles if t.name not in done]
    if missing:
        _remove_mosaics(rec, out_dir)
        failed = {t.name: rec["tiles"].get(t.name, {}).get("error") for t in missing
                  if rec["tiles"].get(t.name, {}).get("status") == "failed"}
        rec["missing_tiles"] = [t.name for t in missing]
        log(f"INCOMPLETE: {len(missing)} of {len(index.tiles)} tile(s) not done, so no dtm.vrt or mask.vrt was "
            f"written (run.json says \"complete\": false): {', '.join(t.name for t in missing[:20])}"
            + (f" and {len(missing) - 20} more" if len(missing) > 20 else "") + ".")
        for name, err in list(failed.items())[:20]:
            log(f"  {name} failed: {err}")
        log(f"Run the same command again with the output folder {out_dir}: the {len(done)} finished tile(s) are "
            "kept and only the missing ones are done, then the mosaics are written.")
        return
    for kind, k in (("dtm", 0), ("mask", 1)):
        files = [os.path.join(out_dir, output_names(t.name)[k]) for t in index.tiles]
        nod = 255 if kind == "mask" else None
        io.build_vrt(os.path.join(out_dir, f"{kind}.vrt"), files, nod, index.tiles[0].unit_type if k == 0 else "")
    grid.write_mask_qml(os.path.join(out_dir, "mask.qml"))
    rec.pop("missing_tiles", None)
    rec["complete"] = True
    rec["mosaics"] = {"dtm": "dtm.vrt", "mask": "mask.vrt", "tiles": len(index.tiles)}
    log(f"Mosaics: dtm.vrt and mask.vrt over all {len(index.tiles)} tile(s).")
