"""Mask codes shared by every filter, the plugin's outputs and the evaluation."""
GROUND = 0   #: bare-earth cell
OBJECT = 1   #: object standing above the ground (building, tree, car, high blunder)
LOW = 2      #: low outlier below the ground (matching blunder, multipath)
NODATA = 255  #: no data in the input

MASK_CODES = {GROUND: "ground", OBJECT: "object above ground",
              LOW: "low outlier below ground", NODATA: "nodata"}

#: RGBA colours of the mask classes (used for the GeoTIFF colour table and QML style).
MASK_COLOURS = {GROUND: (205, 170, 125, 255), OBJECT: (220, 40, 40, 255),
                LOW: (40, 90, 230, 255), NODATA: (0, 0, 0, 0)}


def as_mask_codes(values, nodata, what, remedy):
    """The codes of a mask as uint8, ``nodata`` cells (a boolean array of the same shape) 255.

    A mask holds whole numbers 0-255 (a Bare Earth mask: 0 ground, 1 object, 2 low outlier, 255
    nodata; a classification's codes are accepted too). ValueError naming ``what`` (the mask, its
    file), the number of cells holding anything else and one of them, then ``remedy`` (what to pass
    instead), when a valid cell holds a negative, fractional or larger value: a DSM or a float raster
    given as a mask is refused instead of read as codes (-1 and 256 wrapping to 255, 0.5 to 0).

    >>> import numpy as np
    >>> as_mask_codes(np.array([0., 1., 255., np.nan]), np.array([False, False, False, True]), "m", "")
    array([  0,   1, 255, 255], dtype=uint8)
    """
    import numpy as np

    v = values[~nodata]
    with np.errstate(invalid="ignore"):
        bad = (v < 0) | (v > 255) | (v != np.round(v)) if v.dtype.kind == "f" else (v < 0) | (v > 255)
    if bad.any():
        example = v[bad][0]
        example = f"{float(example):g}" if v.dtype.kind == "f" else f"{example!r}"
        raise ValueError(f"{what} holds {int(np.count_nonzero(bad))} cell(s) that are no mask code (e.g. "
                         f"{example}): a mask holds whole numbers 0-255 (0 ground, 1 object, 2 low outlier, "
                         f"255 nodata; NaN is nodata). {remedy}".rstrip())
    out = np.full(values.shape, NODATA, np.uint8)
    out[~nodata] = v
    return out
