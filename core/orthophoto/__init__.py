"""Orthophoto refinement of a DEM (Luong Chinh Ke 2002, section 2.3; Norvelle 1995).

camera        interior/exterior orientation, omega-phi-kappa, Brown distortion, readers
orthorectify  orthophotos of frame images on a DEM grid
match         normalised cross-correlation along a direction (+ LSM, left-right check)
refine        parallax -> height (eq. 18 and general geometry), one pair, orthoparallax
quality       trusted corrections: blunders, merging pairs, ground trend, object mask
iterate       orthorefine: the iteration over all pairs (Norvelle 1995)
smoothness    roughness (Laplacian sd) and the smooth correction that does not raise it
render        synthetic textured scenes and frames with known truth
affine8       eq. 17: 8-parameter bilinear DEM <-> orthophoto transformation (no orientation)
"""
from .affine8 import Bilinear8, fit_bilinear8, register_orthophoto
from .camera import (
                     Camera,
                     Interior,
                     cameras_from_opk,
                     opk_to_rotation,
                     read_cameras,
                     read_interior_yaml,
                     read_opensfm_reconstruction,
                     read_opk_csv,
                     read_table_rows,
                     rotation_to_opk,
)
from .iterate import RefineResult, cross_check_families, orthorefine, overlapping_pairs, pair_families
from .match import MatchResult, match_along, match_rectified, ncc_volume
from .orthorectify import grid_xy, orthorectify, visibility
from .quality import fill_holes
from .refine import ParallaxResult, orthoparallax, parallax_to_dh, parallax_to_dh_vertical, view_vectors
from .render import OrthoScene, make_ortho_scene, render_frame, render_frames, vertical_cameras

__all__ = ["Bilinear8", "fit_bilinear8", "register_orthophoto",
           "Camera", "Interior", "cameras_from_opk", "opk_to_rotation", "read_cameras",
           "read_interior_yaml",
           "read_opensfm_reconstruction", "read_opk_csv", "read_table_rows", "rotation_to_opk",
           "MatchResult", "match_along", "match_rectified", "ncc_volume",
           "grid_xy", "orthorectify", "visibility",
           "ParallaxResult", "RefineResult", "fill_holes", "orthoparallax", "orthorefine",
           "overlapping_pairs", "pair_families", "cross_check_families", "parallax_to_dh",
           "parallax_to_dh_vertical", "view_vectors",
           "OrthoScene", "make_ortho_scene", "render_frame", "render_frames", "vertical_cameras"]
