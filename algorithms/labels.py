"""Dialog labels of the filters' parameters, written for people, keyed by the core's Param names.

The core's ``Param`` specs give names, kinds, defaults and help; the words a user reads in the
dialog live here, in the QGIS layer. ``METHOD_LABELS`` holds a method's own wording where one
name means something else in another method. An optional parameter whose empty value means
"derived from the data" gets the suffix ``[empty: from the data]`` in :func:`param_label`.
"""

#: label by Param name, shared by every method using the name
LABELS = {
    # slope profile (Luong Chinh Ke 2002, sec. 2.1)
    "slope_threshold_deg": "Terrain slope threshold (degrees)",
    "terrain_slope_deg": "Average terrain slope (degrees)",
    "tolerance_m": "Height tolerance (m)",
    "max_object_size_m": "Largest object (m)",
    "edge_length_m": "Object edge length (m)",
    "sample_spacing_cells": "Spacing of the real samples (cells)",
    "refine": "Give cells close to the ground back to it",
    "slope_factor": "Slope factor of the refinement (m per unit slope)",
    # curvature (sec. 2.2)
    "k_g_per_m2": "Gaussian curvature threshold (1/m²)",
    "window_cells": "Trend window (cells, odd)",
    "model": "Trend surface",
    "min_object_height_m": "Smallest rise into an object (m)",
    "wall_slope_deg": "Smallest wall slope (degrees)",
    # RASCOR (Jacobsen 2004)
    "terrain_class": "Terrain type",
    "homogeneous": "Homogeneous area",
    "sigma_m": "Height accuracy (sigma) of the DSM (m)",
    "step1_characterise": "Step 1: class the terrain",
    "step2_height_distribution": "Step 2: remove heights outside the height distribution",
    "step3_neighbour_differences": "Step 3: remove points above their neighbours",
    "step4_level_change": "Step 4: remove raised levels (buildings)",
    "step5_profiles": "Step 5: moving profiles",
    "step6_surfaces": "Step 6: moving surfaces",
    "step7_prediction": "Step 7: final least-squares prediction",
    "second_iteration": "Repeat steps 3 and 5-7 once",
    "step3_repeat": "Repeat step 3 after steps 4-7",
    "spare_continuing_ground": "Keep smooth ground continuing the ground (embankments, ramps)",
    "height_min_m": "Lowest valid height (m)",
    "height_max_m": "Highest valid height (m)",
    "neighbour_k": "Neighbour test: critical value (x sigma)",
    "terrain_slope": "Neighbour test: terrain slope for a height's place in its cell (rise/run)",
    "terrain_bend_m": "Neighbour and level tests: the terrain's bend over one cell (m)",
    "ground_sigma_m": "Neighbour test: random error of the ground's heights (m)",
    "jump_m": "Smallest jump of level (m)",
    "max_building_m": "Longest building (m)",
    "max_hall_m": "Longest hall closed by walls (m)",
    "short_profile_m": "Short profile length (m)",
    "long_profile_m": "Long profile length (m)",
    "profile_sigma_m": "Height spread about the profiles (m)",
    "surface_size_m": "Moving surface size (m)",
    "surface_rule": "Moving surface size rule",
    "surface_sigma_m": "Height spread about the surfaces (m)",
    "prediction_radius_m": "Prediction radius (m)",
    "prediction_sigma_m": "Height spread of the prediction (m)",
    "snooping_k": "Outlier test: critical value (data snooping)",
    "snooping_iterations": "Fits per profile and surface",
    "low_weight": "Weight of points below the terrain",
    "fits_per_block": "Step 6: fit the surfaces once per block of cells (faster)",
    # geodesic dilation
    "min_window_m": "Smallest window (m)",
    "height_threshold_m": "Lowest object height (m)",
    "edge_ratio": "Edge heterogeneity threshold (0-1)",
    "outlier_threshold_m": "Outlier height difference (m)",
    "outlier_width_m": "Outlier search window (m)",
    "scan_labelling": "Scan labelling after the dilation",
    # morphological
    "mode": "Single or progressive windows",
    "dh_m": "Object height threshold (m)",
    "slope": "Terrain slope (rise/run)",
    "slope_scale_m": "Slope tolerance of the final test (m per unit slope)",
    "window_growth": "Window growth between steps",
    "low_outlier_slope": "Low-outlier test slope (rise/run)",
    "outline_slope": "Terrain slope beside objects (rise/run)",
    "wide_slope": "Terrain slope of the wide windows (rise/run)",
    "wide_radius_m": "Radius where the wide windows begin (m)",
    "noise_m": "Noise of the ground (sigma, m)",
    "raised_regions": "Widen the derived window to roofs standing on walls",
    "reference_slopes": "Pass crests the reference window's slopes allow (raised roads, dikes)",
}

#: a method's own wording of a shared name: {(method, name): label}
METHOD_LABELS = {
    ("curvature", "tolerance_m"): "Height above the interpolated ground still ground (m)",
    ("curvature", "max_object_size_m"): "Largest object (m)",
    ("curvature", "spacing_m"): "Wall test: spacing of the independent heights (m)",
    ("curvature", "terrain_slope"): "Wall test: the terrain's steep slope (rise/run)",
    ("geodesic", "terrain_slope_deg"): "Steepest terrain slope tolerated (degrees)",
    ("geodesic", "max_object_size_m"): "Largest object: widest building (m)",
    ("morphological", "max_object_size_m"): "Largest object: largest window (m)",
}

#: parameters shown in the dialog's advanced section although the core's spec shows them:
#: RASCOR's step switches (the defaults run the paper's sequence)
ADVANCED = {("rascor", n) for n in ("step1_characterise", "step2_height_distribution",
                                    "step3_neighbour_differences", "step4_level_change", "step5_profiles",
                                    "step6_surfaces", "step7_prediction", "second_iteration",
                                    "step3_repeat", "spare_continuing_ground")}


#: short names of the filters' side products (dialog labels and layer names), by the core's extras key
EXTRA_LABELS = {"curvature": "Curvature (K, H)", "step": "Removal step", "confidence": "Confidence (%)"}


def extra_label(key):
    """The short label of a side product (its key, capitalised, when it has none)."""
    return EXTRA_LABELS.get(key, key.replace("_", " ").capitalize())


def has_label(method, name):
    """True when the parameter ``name`` of ``method`` has a hand-written label."""
    return (method, name) in METHOD_LABELS or name in LABELS


def param_label(method, param):
    """The dialog label of a core ``Param`` of ``method`` (generated from its name only when
    no label was written, so a new parameter still shows)."""
    label = METHOD_LABELS.get((method, param.name)) or LABELS.get(param.name)
    if label is None:
        label = param.name.replace("_", " ")
        label = label[0].upper() + label[1:]
    if param.default is None:
        label += " [empty: from the data]"
    return label


def is_advanced(method, param):
    """Whether the parameter goes to the dialog's advanced section."""
    return bool(param.advanced) or (method, param.name) in ADVANCED
