"""``bareearth:evaluate``: compare a result with truth (masks, DTMs, or points)."""
import os

import numpy as np
from qgis.core import (
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
)

from ..core import Cancelled, grid
from ..core import evaluate as ev
from ..core.pointfiles import is_class_column
from ..core.pointflow import class_counts, classify_cloud, truth_ground
from ..core.points import read_points
from .compat import NUMBER_DOUBLE, mark_advanced
from .fill_dtm import grid_mismatch_message, same_grid
from .filter_base import (
    BaseAlgorithm,
    explained,
    open_one_band,
    stage_done,
    tr,
    with_help,
)

#: what each figure of a comparison is, for the log (Sithole & Vosselman 2004's cross matrix:
#: rows the truth, columns the result)
FIGURES = {
    "a": "a: ground kept as ground",
    "b": "b: ground rejected (Type I errors)",
    "c": "c: objects accepted as ground (Type II errors)",
    "d": "d: objects rejected",
    "n": "compared",
    "n_ground": "of which ground (a + b)",
    "n_object": "of which objects (c + d)",
    "type1": "Type I error, b / (a + b)",
    "type2": "Type II error, c / (c + d)",
    "total": "Total error, (b + c) / n",
    "kappa": "Cohen's kappa",
    "points_outside_dtm": "points outside the DTM (not counted)",
    "rmse": "RMSE (m)", "mean": "mean error (m)", "max_abs": "largest error (m)",
    "ground_rmse": "RMSE on reference ground (m)", "ground_mean": "mean error on reference ground (m)",
    "ground_max_abs": "largest error on reference ground (m)", "ground_n": "reference ground cells compared",
}
PERCENT_FIGURES = ("type1", "type2", "total", "kappa")


def log_figures(feedback, name, figures):
    """One comparison in the log: what each figure is, percentages with '%', counts as integers
    in cells or points."""
    unit = tr("points") if "point" in name else tr("cells")
    feedback.pushInfo("{}:".format(name))
    width = max(len(tr(FIGURES.get(k, k))) for k in figures)
    for k, v in figures.items():
        label = tr(FIGURES.get(k, k)).ljust(width)
        if k in PERCENT_FIGURES:
            text = tr("not defined") if v is None or v != v else "{:.4g} %".format(v)
        elif isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            text = "{} {}".format(int(v), unit)
        elif isinstance(v, float):
            text = "{:.4g}".format(v)
        else:
            text = str(v)
        feedback.pushInfo("  {}  {}".format(label, text))


class EvaluateAlgorithm(BaseAlgorithm):
    """Type I / Type II / total error / kappa, and DTM height errors, with JSON and HTML reports."""

    MASK, REFERENCE_MASK, DTM, REFERENCE_DTM, POINTS = "MASK", "REFERENCE_MASK", "DTM", "REFERENCE_DTM", "POINTS"
    THRESHOLD_M, SLOPE_FACTOR = "THRESHOLD_M", "SLOPE_FACTOR"
    TRUTH_POINTS, TRUTH_COLUMN = "TRUTH_POINTS", "TRUTH_COLUMN"
    OUTPUT_JSON, OUTPUT_HTML = "OUTPUT_JSON", "OUTPUT_HTML"
    GROUP, GROUP_NAME = "tools", "DTM tools"
    TAGS = ("DTM", "DEM", "ground", "terrain", "bare earth", "evaluate", "accuracy", "error", "RMSE", "kappa",
            "ISPRS", "Type I", "Type II", "lidar", "reference")

    def name(self):
        return "evaluate"

    def displayName(self):  # noqa: N802
        return tr("Evaluate against reference data")

    def shortHelpString(self):  # noqa: N802
        return tr(
            "<p>Compares a filter's result with truth, in any of three ways (give at least one pair):</p><ul>"
            "<li><b>MASK</b> against <b>REFERENCE_MASK</b> (codes 0 ground, 1/2 object, 255 ignored). A mask "
            "holding only 0 and 255 whose 255 cells lie mostly on the other mask's objects (a 0/255 binary mask: "
            "its objects would be left out and the total error would count the ground alone) is refused before "
            "any work: reclassify it to 0 ground and 1 object.</li>"
            "<li><b>DTM</b> against <b>REFERENCE_DTM</b>: RMSE, mean and max error over all cells, and over "
            "the reference mask's ground cells when a REFERENCE_MASK is given.</li>"
            "<li><b>POINTS</b> (ISPRS text 'x y z class' with class 0 = ground, or a classified LAS/LAZ "
            "file where ASPRS class 2 = ground) classified by the <b>DTM</b>: ground when |z - DTM| &lt;= "
            "THRESHOLD_M + SLOPE_FACTOR x local DTM slope (Pingel et al. 2013).</li>"
            "<li>Classified <b>POINTS</b> (e.g. the output of classifypoints or of a filter's INPUT_POINTS: "
            "text class 0 = ground, 255 = not classified; LAS class 2 = ground) against per-point truth: "
            "<b>TRUTH_POINTS</b>, the same points with their true classes (ISPRS text 0/1, or LAS with ASPRS "
            "class 2 = ground; matched by position), or <b>TRUTH_COLUMN</b>, a column of POINTS (text header "
            "name or LAS dimension) holding the truth. No DTM is needed.</li></ul>"
            "<p>Reports Type I (ground rejected / ground), Type II (objects accepted as ground / "
            "objects), total error and Cohen's kappa (Sithole &amp; Vosselman 2004) as a table in the log, "
            "a JSON file and an HTML report with a map of the Type I and Type II errors (each optional: "
            "either alone will do).</p>")

    def initAlgorithm(self, config=None):  # noqa: N802
        for key, label, help_ in (
                (self.MASK, "Mask to evaluate", "UInt8 mask of a filter (0 ground, 1/2 object, 255 nodata)."),
                (self.REFERENCE_MASK, "Reference mask", "Truth mask on the same grid, same codes."),
                (self.DTM, "DTM to evaluate", "Filtered DTM (compared with REFERENCE_DTM, or used to "
                                              "classify POINTS)."),
                (self.REFERENCE_DTM, "Reference DTM", "Truth DTM on the same grid as DTM.")):
            p = QgsProcessingParameterRasterLayer(key, tr(label), optional=True)
            p.setHelp(tr(help_))
            self.addParameter(p)
        p = QgsProcessingParameterFile(self.POINTS, tr("Reference points (ISPRS text or LAS/LAZ)"),
                                       optional=True)
        p.setHelp(tr("Points with per-point truth: text 'x y z class' (class 0 = ground, ISPRS) or LAS/LAZ "
                     "(ASPRS class 2 = ground; needs laspy, and lazrs for LAZ). With TRUTH_POINTS or TRUTH_COLUMN: "
                     "classified points (their class is the prediction)."))
        self.addParameter(p)
        p = QgsProcessingParameterFile(self.TRUTH_POINTS, tr("Truth points for classified POINTS"),
                                       optional=True)
        p.setHelp(tr("With classified POINTS: the same points with their true classes (ISPRS text class 0 = "
                     "ground, or LAS/LAZ with ASPRS class 2 = ground), matched by position."))
        self.addParameter(p)
        p = QgsProcessingParameterString(self.TRUTH_COLUMN, tr("Truth column of classified POINTS"),
                                         optional=True)
        p.setHelp(tr("With classified POINTS: the name of their column (text header) or LAS dimension holding "
                     "the true class (0 = ground for text, 2 = ground for LAS)."))
        mark_advanced(p)
        self.addParameter(p)
        t = QgsProcessingParameterNumber(self.THRESHOLD_M, tr("Ground tolerance (m)"),
                                         NUMBER_DOUBLE, 0.5, minValue=0.0)
        t.setHelp(tr("A point within this height of the DTM, plus the slope term, is ground (metres)."))
        mark_advanced(t)
        self.addParameter(t)
        s = QgsProcessingParameterNumber(self.SLOPE_FACTOR, tr("Slope factor"),
                                         NUMBER_DOUBLE, 1.25, minValue=0.0)
        s.setHelp(tr("Multiplies the local DTM slope (rise/run) in the point tolerance (SMRF: 1.25)."))
        mark_advanced(s)
        self.addParameter(s)
        # each report is optional: either alone will do, and with neither the figures are the log's
        # table and the numbers below (a model's next step reads them)
        self.addParameter(with_help(QgsProcessingParameterFileDestination(
            self.OUTPUT_JSON, tr("Figures (JSON)"), "JSON files (*.json)", optional=True),
            "All figures as JSON (Type I/II, total, kappa in percent; DTM errors in metres). Optional."))
        self.addParameter(with_help(QgsProcessingParameterFileDestination(
            self.OUTPUT_HTML, tr("Report (HTML)"), "HTML files (*.html)", optional=True),
            "Self-contained HTML report: the table and a map of the Type I and Type II errors. Optional."))
        for key, label in (("TYPE1", "Type I (%)"), ("TYPE2", "Type II (%)"), ("TOTAL", "Total error (%)"),
                           ("KAPPA", "Kappa (%)"), ("RMSE", "DTM RMSE (m)")):
            self.addOutput(QgsProcessingOutputNumber(key, tr(label)))

    def _layer(self, parameters, key, context):
        """The raster of ``key`` as its QGIS layer stands: its additional no-data values and, for a
        file without a CRS, the CRS it was given (a DTM in feet is compared in metres)."""
        lay = self.parameterAsRasterLayer(parameters, key, context)
        if lay is None:
            return None
        return open_one_band(lay, key)

    def _inputs(self, parameters, context):
        mask = self._layer(parameters, self.MASK, context)
        ref_mask = self._layer(parameters, self.REFERENCE_MASK, context)
        dtm, ref_dtm = self._layer(parameters, self.DTM, context), self._layer(parameters, self.REFERENCE_DTM, context)
        points = self.parameterAsFile(parameters, self.POINTS, context) or None
        truth, column = self._truth(parameters, context)
        if (truth or column) and not points:
            raise ValueError("TRUTH_POINTS / TRUTH_COLUMN are the truth of classified POINTS: give POINTS too.")
        if truth and column:
            raise ValueError("Give the truth once: TRUTH_POINTS or TRUTH_COLUMN, not both.")
        if truth and not os.path.isfile(truth):
            raise ValueError(f"The truth points file {truth!r} does not exist.")
        if (mask is None) != (ref_mask is None) and ref_dtm is None:
            raise ValueError("MASK and REFERENCE_MASK go together: give both, or neither.")
        if mask is not None and ref_mask is None:
            raise ValueError("MASK is compared with REFERENCE_MASK: give REFERENCE_MASK too, or leave MASK out "
                             "(it would not be used).")
        if ref_dtm is not None and dtm is None:
            raise ValueError("REFERENCE_DTM needs a DTM to compare with.")
        if points and dtm is None and not (truth or column):
            raise ValueError("POINTS are classified by a DTM: give the DTM too (or, for points that are "
                             "already classified, their truth as TRUTH_POINTS or TRUTH_COLUMN).")
        if not ((mask is not None and ref_mask is not None) or ref_dtm is not None or points):
            raise ValueError("Nothing to compare: give MASK and REFERENCE_MASK, DTM and REFERENCE_DTM, "
                             "or POINTS and DTM.")
        if mask is not None and ref_mask is not None and not same_grid(mask, ref_mask, heights=False):
            raise ValueError(grid_mismatch_message(mask, ref_mask, "The reference mask", of="the mask", heights=False))
        for d, name in ((dtm, "DTM"), (ref_dtm, "REFERENCE_DTM")):
            if d is not None and (ref_dtm is not None or points):
                try:
                    grid.check_has_data(d)
                except ValueError as exc:
                    raise ValueError(f"{name}: {exc}") from None
        read = {}
        for m, name in ((mask, "The mask (MASK)"), (ref_mask, "The reference mask (REFERENCE_MASK)")):
            if m is not None:
                read[m is ref_mask] = codes = grid.read_mask(m, name)   # codes, not heights: refused now
                if m is ref_mask:
                    ev.check_reference_mask(codes, f"{name} {m.path!r}")
        if len(read) == 2:     # a 0/255 binary mask: its objects read as nodata, left out of the comparison
            ev.check_nodata_not_objects(read[False], read[True], f"The mask (MASK) {mask.path!r}",
                                        "the reference mask")
            ev.check_nodata_not_objects(read[True], read[False],
                                        f"The reference mask (REFERENCE_MASK) {ref_mask.path!r}", "the mask")
        if ref_dtm is not None and not same_grid(dtm, ref_dtm):
            raise ValueError(grid_mismatch_message(dtm, ref_dtm, "The reference DTM", of="the DTM"))
        if ref_dtm is not None and ref_mask is not None and not same_grid(dtm, ref_mask, heights=False):
            # its ground cells select the DTM's cells of the ground errors: another grid picks others
            raise ValueError(grid_mismatch_message(dtm, ref_mask, "The reference mask (REFERENCE_MASK), whose "
                                                   "ground cells the DTM's errors are measured on,", of="the DTM",
                                                   heights=False))
        if points and not os.path.isfile(points):
            raise ValueError(f"The points file {points!r} does not exist.")
        for a, b, what in ((mask, ref_mask, "MASK and REFERENCE_MASK"), (dtm, ref_dtm, "DTM and REFERENCE_DTM")):
            if a is not None and b is not None and grid.file_identity(a.path) == grid.file_identity(b.path):
                raise ValueError(f"{what} are one file ({a.path}{'' if a.path == b.path else ' and ' + b.path}): it "
                                 "would be compared with itself (no error at all). Give the result as the first and "
                                 "the reference (the truth) as the second.")
        if points and truth and grid.file_identity(points) == grid.file_identity(truth):
            raise ValueError(f"TRUTH_POINTS and POINTS are one file ({points}): the classes would be compared with "
                             "themselves (no error at all). Give the classified points as POINTS and the file with "
                             "the true classes as TRUTH_POINTS.")
        if points and column and is_class_column(points, column):
            raise ValueError(f"TRUTH_COLUMN '{column}' is the column the classes of POINTS are read from: they "
                             "would be compared with themselves (no error at all). Give the column that holds the "
                             "true classes, or the original file as TRUTH_POINTS (classifypoints and the filters "
                             "overwrite a LAS file's classification).")
        return mask, ref_mask, dtm, ref_dtm, points

    def _truth(self, parameters, context):
        truth = self.parameterAsFile(parameters, self.TRUTH_POINTS, context) or None
        column = (self.parameterAsString(parameters, self.TRUTH_COLUMN, context) or "").strip() or None
        return truth, column

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        try:
            self._inputs(parameters, context)
        except (ValueError, QgsProcessingException) as exc:
            return False, str(exc)
        return True, ""

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        try:
            return self._evaluate(parameters, context, feedback)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}

    def _evaluate(self, parameters, context, feedback):
        try:
            mask, ref_mask, dtm, ref_dtm, points = self._inputs(parameters, context)
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        stage_done(feedback, 5)
        results, maps, gts = {}, {}, {}
        out = {}
        ref_m = None
        if ref_mask is not None:
            ref_m = grid.read_mask(ref_mask, "The reference mask (REFERENCE_MASK)")
        if mask is not None and ref_mask is not None:
            m = grid.read_mask(mask, "The mask (MASK)")
            r = ev.compare_masks(m, ref_m)
            results["mask vs reference mask"] = r
            maps["mask errors"], _ = ev.error_map_from_masks(m, ref_m)
            gts["mask errors"] = mask.geotransform
            out.update(TYPE1=r["type1"], TYPE2=r["type2"], TOTAL=r["total"], KAPPA=r["kappa"])
            stage_done(feedback, 30)
        if ref_dtm is not None:
            d = ev.compare_dtm(dtm.read(), ref_dtm.read(),
                               ground=None if ref_m is None else (ref_m == 0))
            results["DTM vs reference DTM"] = d
            out["RMSE"] = d["rmse"]
            stage_done(feedback, 50)
        truth, column = self._truth(parameters, context)
        if points and (truth or column):
            from .points import evaluate_classified
            if truth:
                feedback.pushInfo(tr("Comparing the classified points {} with the truth points {} ...").format(
                    points, truth))
            else:
                feedback.pushInfo(tr("Comparing the classified points {} with their column '{}' ...").format(
                    points, column))
            try:
                r, maps["point errors"], gts["point errors"] = evaluate_classified(points, truth, column)
            except (ValueError, ImportError) as exc:
                raise QgsProcessingException(self.explain(str(exc))) from None
            results["classified points vs truth"] = r
            out.update(TYPE1=r["type1"], TYPE2=r["type2"], TOTAL=r["total"], KAPPA=r["kappa"])
        elif points:
            feedback.pushInfo(tr("Reading points {} ...").format(points))
            try:
                cloud = read_points(points)
            except (ValueError, ImportError) as exc:
                raise QgsProcessingException(self.explain(str(exc))) from None
            if cloud.classification is None:
                raise QgsProcessingException(tr("The points file '{}' has no class column: it cannot serve as "
                                                "truth.").format(points))
            from .points import crs_warning, height_mismatch_warning
            w = crs_warning(cloud, dtm)
            if w:
                feedback.pushWarning(w)
            try:
                true_ground = truth_ground(cloud.classification, cloud.source_format, "The points (POINTS)")
                # in metres whatever the units (feet: the tolerance stays 0.5 m)
                cls = classify_cloud(cloud, dtm.read(), dtm.geotransform,
                                     threshold_m=self.parameterAsDouble(parameters, self.THRESHOLD_M, context),
                                     slope_factor=self.parameterAsDouble(parameters, self.SLOPE_FACTOR, context))
            except ValueError as exc:
                raise QgsProcessingException(self.explain(str(exc))) from None
            inside = cls != 255
            w = height_mismatch_warning(class_counts(cls))
            if w:
                feedback.pushWarning(w)
            r = ev.confusion(cls == 0, true_ground, valid=inside)
            r["points_outside_dtm"] = int((~inside).sum())
            results["points classified by the DTM"] = r
            maps["point errors"], _ = ev.error_map_from_points(cls == 0, true_ground, cloud.x, cloud.y,
                                                              dtm.geotransform, dtm.shape, valid=inside)
            gts["point errors"] = dtm.geotransform
            out.update(TYPE1=r["type1"], TYPE2=r["type2"], TOTAL=r["total"], KAPPA=r["kappa"])
        stage_done(feedback, 90)
        for name, r in results.items():
            log_figures(feedback, name, r)
        json_path = self.parameterAsFileOutput(parameters, self.OUTPUT_JSON, context) or None
        html_path = self.parameterAsFileOutput(parameters, self.OUTPUT_HTML, context) or None
        if json_path or html_path:
            try:
                ev.write_report(results, json_path=json_path, html_path=html_path, error_map=maps or None,
                                geotransform=gts or None, title="Bare Earth evaluation")
            except ValueError as exc:
                raise QgsProcessingException(self.explain(str(exc))) from None
        out.update({k: v for k, v in ((self.OUTPUT_JSON, json_path), (self.OUTPUT_HTML, html_path)) if v})
        return out
