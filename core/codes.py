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
