"""How Processing shows the outputs it loads: the mask's four classes, and renderers for the
side products (QGIS ignores a ``.qml`` beside a file it loads as a Processing result, and would
show the GeoTIFF's 256-entry palette, or an RGB composite of a two-band raster).

:func:`style_loaded_outputs` gives each output Processing will load a layer post-processor
(``QgsProcessingLayerPostProcessorInterface``) that sets the renderer once the layer exists.
"""
from qgis.core import (
    QgsColorRampShader,
    QgsGradientColorRamp,
    QgsGradientStop,
    QgsPalettedRasterRenderer,
    QgsProcessingLayerPostProcessorInterface,
    QgsRasterLayer,
    QgsRasterShader,
    QgsSingleBandPseudoColorRenderer,
)
from qgis.PyQt.QtGui import QColor

from ..core.codes import MASK_CODES, MASK_COLOURS, NODATA
from .compat import SHADER_LINEAR

#: renderer of each output, by output parameter
OUTPUT_RENDERERS = {"OUTPUT_MASK": "mask", "OUTPUT_CURVATURE": "curvature", "OUTPUT_STEP": "steps",
                    "OUTPUT_CONFIDENCE": "confidence"}


def mask_renderer(layer):
    """The four mask classes: 0 ground, 1 object above the ground, 2 low outlier, 255 nodata."""
    classes = [QgsPalettedRasterRenderer.Class(code, QColor(*MASK_COLOURS[code]), MASK_CODES[code])
               for code in sorted(MASK_CODES)]
    return QgsPalettedRasterRenderer(layer.dataProvider(), 1, classes)


def _ramp_renderer(layer, lo, hi, stops, band=1):
    """Single-band pseudocolour of ``band`` from ``lo`` to ``hi`` through ``stops`` [(t, QColor)]."""
    ramp = QgsGradientColorRamp(stops[0][1], stops[-1][1], False,
                                [QgsGradientStop(t, c) for t, c in stops[1:-1]])
    shader_fn = QgsColorRampShader(lo, hi, ramp, SHADER_LINEAR)
    shader_fn.classifyColorRamp(5, band, layer.extent(), layer.dataProvider())
    shader = QgsRasterShader(lo, hi)
    shader.setRasterShaderFunction(shader_fn)
    r = QgsSingleBandPseudoColorRenderer(layer.dataProvider(), band, shader)
    r.setClassificationMin(lo)
    r.setClassificationMax(hi)
    return r


def curvature_renderer(layer):
    """Gaussian curvature K (band 1), blue (K < 0, saddles) - white - red (K > 0, domes and
    hollows), symmetric about 0 over the 2-98 % range of |K|."""
    lo, hi = layer.dataProvider().cumulativeCut(1, 0.02, 0.98)
    lim = max(abs(lo), abs(hi)) or 1e-6
    return _ramp_renderer(layer, -lim, lim, [(0.0, QColor(33, 102, 172)), (0.5, QColor(247, 247, 247)),
                                             (1.0, QColor(178, 24, 43))])


def confidence_renderer(layer):
    """Confidence in percent, red (0) - yellow - green (100)."""
    return _ramp_renderer(layer, 0.0, 100.0, [(0.0, QColor(215, 25, 28)), (0.5, QColor(255, 255, 191)),
                                              (1.0, QColor(26, 150, 65))])


def steps_renderer(layer):
    """The step that removed each cell: 0 kept (grey), one colour per step found, 255 nodata."""
    values = sorted(c.value for c in QgsPalettedRasterRenderer.classDataFromRaster(layer.dataProvider(), 1))
    steps = [v for v in values if 0 < v < NODATA]
    classes = [QgsPalettedRasterRenderer.Class(0, QColor(220, 220, 220), "kept")]
    for i, v in enumerate(steps):
        hue = int(300 * i / max(1, len(steps) - 1)) if len(steps) > 1 else 0
        classes.append(QgsPalettedRasterRenderer.Class(int(v), QColor.fromHsv(hue, 200, 220),
                                                       "removed by step {}".format(int(v))))
    return QgsPalettedRasterRenderer(layer.dataProvider(), 1, classes)


RENDERERS = {"mask": mask_renderer, "curvature": curvature_renderer, "steps": steps_renderer,
             "confidence": confidence_renderer}


class OutputStyler(QgsProcessingLayerPostProcessorInterface):
    """Sets one output's renderer when Processing has loaded it."""

    #: QGIS holds post-processors by pointer only: Python keeps them alive
    _alive = []

    def __init__(self, kind):
        super().__init__()
        self.kind = kind

    @classmethod
    def create(cls, kind):
        styler = cls(kind)
        cls._alive.append(styler)
        return styler

    def postProcessLayer(self, layer, context, feedback):  # noqa: N802
        if not isinstance(layer, QgsRasterLayer) or not layer.isValid():
            return
        renderer = RENDERERS[self.kind](layer)
        layer.setRenderer(renderer)
        layer.triggerRepaint()


def style_loaded_outputs(alg, context):
    """Give each output of ``alg`` that Processing will load its renderer's post-processor."""
    for path, details in context.layersToLoadOnCompletion().items():
        kind = OUTPUT_RENDERERS.get(details.outputName)
        if kind is None or alg.outputDefinition(details.outputName) is None and \
                alg.parameterDefinition(details.outputName) is None:
            continue
        context.layerToLoadOnCompletionDetails(path).setPostProcessor(OutputStyler.create(kind))
