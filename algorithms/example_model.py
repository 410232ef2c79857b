"""Build ``examples/rasterize_filter_classify.model3``: points -> DSM -> filter -> classified points.

A Processing model made with the Python API (QgsProcessingModelAlgorithm), not by hand; it
lives in the plugin's QGIS layer because it is QGIS code (the numeric core stays QGIS-free):

    rasterizepoints (lowest point per cell)  ->  <filter> (default: morphological)  ->  classifypoints

Model inputs: ``points`` (text/CSV or LAS/LAZ), ``cell_size_m`` (optional, empty = from the
point density), ``threshold_m`` and ``slope_factor`` (the point rule, 0.5 m / 1.25).
Model outputs: ``classified`` (points with their class), ``dtm`` and ``mask`` (rasters).
Any Bare Earth filter can replace the middle step (``--filter slopeprofile``): every filter
takes a DSM ``INPUT`` and gives ``OUTPUT_DTM`` / ``OUTPUT_MASK``.

Usage (QGIS's Python, headless)::

    PYTHONPATH=.build/plugins QT_QPA_PLATFORM=offscreen /usr/bin/python3 \\
        -m bare_earth.algorithms.example_model [--filter NAME] [OUT]

Run the model::

    qgis_process.bin run examples/rasterize_filter_classify.model3 -- points=samp11.txt \\
        classify:classified=classified.txt filter:dtm=dtm.tif filter:mask=mask.tif

(``qgis_process help examples/rasterize_filter_classify.model3`` lists the exact names.)
"""
import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent   # the plugin folder
EXAMPLES = ROOT / "examples"


def build(filter_name="morphological"):
    """Return the model (QgsProcessingModelAlgorithm); QGIS must be initialised."""
    from qgis.core import (
        QgsApplication,
        QgsProcessingModelAlgorithm,
        QgsProcessingModelChildAlgorithm,
        QgsProcessingModelChildParameterSource,
        QgsProcessingModelOutput,
        QgsProcessingModelParameter,
        QgsProcessingParameterFile,
        QgsProcessingParameterNumber,
    )
    from qgis.PyQt.QtCore import QPointF

    from .compat import FILE_FILE, NUMBER_DOUBLE, is_optional

    model = QgsProcessingModelAlgorithm("Rasterize, filter and classify points", "Bare Earth examples",
                                        "bareearthexamples")
    model.setHelpContent({
        "ALG_DESC": ("Point cloud (text/CSV 'x y z [class]' or LAS/LAZ) -> DSM of the lowest point per cell "
                     f"(bareearth:rasterizepoints) -> bareearth:{filter_name} -> every point classified ground / "
                     "above / below the DTM (bareearth:classifypoints, SMRF rule)."),
        "points": "Point file: text/CSV x y z [class] or LAS/LAZ (laspy needed for LAS).",
        "cell_size_m": "Cell size in metres; empty: about one point per cell, at most 1 m.",
        "threshold_m": "Ground tolerance in metres (SMRF 0.5).",
        "slope_factor": "Extra tolerance per unit of DTM slope, metres (SMRF 1.25).",
    })

    def add_input(param, x, y):
        mp = QgsProcessingModelParameter(param.name())
        mp.setPosition(QPointF(x, y))
        model.addModelParameter(param, mp)

    add_input(QgsProcessingParameterFile("points", "Points (text/CSV or LAS/LAZ)", FILE_FILE,
                                         "", None, False,
                                         "Point clouds (*.txt *.csv *.xyz *.pts *.las *.laz);;All files (*.*)"),
              120, 60)
    add_input(QgsProcessingParameterNumber("cell_size_m", "Cell size (m) [empty: from the point density]",
                                           NUMBER_DOUBLE, None, True, 0.0, 100000.0),
              340, 60)
    add_input(QgsProcessingParameterNumber("threshold_m", "Ground tolerance (m)",
                                           NUMBER_DOUBLE, 0.5, False, 0.0, 1000.0), 560, 60)
    add_input(QgsProcessingParameterNumber("slope_factor", "Slope factor (m per unit slope)",
                                           NUMBER_DOUBLE, 1.25, False, 0.0, 1000.0), 780, 60)

    src = QgsProcessingModelChildParameterSource

    def fill_defaults(child):
        """Static default values for the mandatory parameters not linked to anything."""
        alg = QgsApplication.processingRegistry().algorithmById(child.algorithmId())
        if alg is None:
            raise RuntimeError(f"{child.algorithmId()} is not registered: is the Bare Earth plugin loaded?")
        for d in alg.parameterDefinitions():
            if d.isDestination() or d.name() in child.parameterSources() or \
                    is_optional(d):
                continue
            child.addParameterSources(d.name(), [src.fromStaticValue(d.defaultValue())])

    # 1. rasterize
    rast = QgsProcessingModelChildAlgorithm("bareearth:rasterizepoints")
    rast.setChildId("rasterize")
    rast.setDescription("Rasterize points (lowest per cell)")
    rast.setPosition(QPointF(220, 200))
    rast.addParameterSources("INPUT", [src.fromModelParameter("points")])
    rast.addParameterSources("CELL_SIZE_M", [src.fromModelParameter("cell_size_m")])
    rast.addParameterSources("REDUCER", [src.fromStaticValue(0)])
    rast.addParameterSources("FILL_EMPTY", [src.fromStaticValue(True)])
    fill_defaults(rast)
    model.addChildAlgorithm(rast)

    # 2. any filter: the DSM in, DTM and mask out
    filt = QgsProcessingModelChildAlgorithm(f"bareearth:{filter_name}")
    filt.setChildId("filter")
    filt.setDescription(f"Filter the DSM ({filter_name})")
    filt.setPosition(QPointF(440, 320))
    filt.addParameterSources("INPUT", [src.fromChildOutput("rasterize", "OUTPUT")])
    outputs = {}
    for key, name, label, y in (("OUTPUT_DTM", "dtm", "DTM", 300), ("OUTPUT_MASK", "mask", "Object mask", 360)):
        out = QgsProcessingModelOutput(name, label)
        out.setChildId("filter")
        out.setChildOutputName(key)
        out.setPosition(QPointF(660, y))
        outputs[name] = out
    filt.setModelOutputs(outputs)
    fill_defaults(filt)
    model.addChildAlgorithm(filt)

    # 3. classify the points by the DTM
    cls = QgsProcessingModelChildAlgorithm("bareearth:classifypoints")
    cls.setChildId("classify")
    cls.setDescription("Classify points by the DTM")
    cls.setPosition(QPointF(660, 460))
    cls.addParameterSources("INPUT", [src.fromModelParameter("points")])
    cls.addParameterSources("DTM", [src.fromChildOutput("filter", "OUTPUT_DTM")])
    cls.addParameterSources("THRESHOLD_M", [src.fromModelParameter("threshold_m")])
    cls.addParameterSources("SLOPE_FACTOR", [src.fromModelParameter("slope_factor")])
    out = QgsProcessingModelOutput("classified", "Classified points")
    out.setChildId("classify")
    out.setChildOutputName("OUTPUT")
    out.setPosition(QPointF(880, 500))
    cls.setModelOutputs({"classified": out})
    fill_defaults(cls)
    model.addChildAlgorithm(cls)
    model.updateDestinationParameters()
    return model


def _init_qgis():
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    plugins = ROOT / ".build" / "plugins"
    for p in (str(plugins), "/usr/share/qgis/python/plugins"):
        if p not in sys.path:
            sys.path.insert(0, p)
    from qgis.core import QgsApplication
    app = QgsApplication.instance() or QgsApplication([], False)
    app.initQgis()
    from processing.core.Processing import Processing
    Processing.initialize()
    from bare_earth.plugin import BareEarthPlugin
    plugin = BareEarthPlugin(None)
    plugin.initProcessing()
    return app, plugin


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", nargs="?", default=str(EXAMPLES / "rasterize_filter_classify.model3"))
    ap.add_argument("--filter", default="morphological", help="the middle step (a bareearth filter name)")
    args = ap.parse_args(argv)
    app, plugin = _init_qgis()
    model = build(args.filter)
    ok, errors = model.validate() if hasattr(model, "validate") else (True, [])
    if not ok:
        print("model does not validate:", errors, file=sys.stderr)
        return 1
    if not model.toFile(args.out):
        print(f"cannot write {args.out}", file=sys.stderr)
        return 1
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
