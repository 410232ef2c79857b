"""Local-trend filter by Gaussian curvature (Luong Chinh Ke 2002, section 2.2).

Luong Chinh Ke (2002) fits local trends of the surface to groups of neighbouring points
along profiles in X (Y constant) and in Y (X constant), at least five points per group,
by least squares, and gives each point the Gaussian curvature of the fitted surface

    K = (r t - s^2) / h^4,      h^2 = 1 + p^2 + q^2                      (eqs. 9-16)

with p = dz/dX, q = dz/dY the first and r = d2z/dX2, s = d2z/dXdY, t = d2z/dY2 the
second derivatives. A point with ``|K| >= K_g`` lies on a break of the surface: at the foot
or the top of an object.

Local trend surfaces
--------------------
``"quadratic"`` (default)
    z = a + b x + c y + d x^2 + e x y + f y^2 fitted by least squares to the
    ``window x window`` cells around every cell (Evans-Young / Zevenbergen-Thorne style):
    p = b, q = c, r = 2 d, s = e, t = 2 f. On a regular grid the normal equations
    separate, so every coefficient is a separable kernel: the whole raster is done with a
    few shifted sums (no loop per cell). Besides K it gives the mean curvature H, whose
    sign separates convex (H > 0) from concave (H < 0) where K alone cannot (K > 0 for a
    dome and for a bowl alike).
``"bilinear"``
    The paper's surface z = a0 + a1 X + a2 Y + a3 X Y (eq. 12), fitted to the window of
    ``window`` neighbouring X profiles (fitted to the points of a single profile it is
    degenerate: with Y constant, a2 and a3 cannot be separated). Its second derivatives
    are r = t = 0, s = a3, so K = -a3^2 / h^4 is never positive: it finds twisted
    breaks (corners) but cannot tell convex from concave, and misses straight edges.

From curvature to objects
-------------------------
1. **Breaks.** A cell is marked when ``|K| >= K_g`` (the paper's test), or by its X
   profile when the bend of the X trend ``|r| >= sqrt(K_g)``, or by its Y profile when
   ``|t| >= sqrt(K_g)``. The profile tests are needed: along a straight roof edge one
   principal curvature is zero, so K = 0, and a tall wall has a tiny K (h^4 is large),
   but the profile across the edge bends strongly. ``sqrt(K_g)`` is the bend of a point
   curved as much both ways (K = kappa^2).
2. **Profiles.** Along every X and Y profile (each scanned both ways, all profiles at
   once) the points between a break going up and the matching break coming down belong
   to an object: the object starts at a marked cell on top of a wall (a rise of at least
   the minimum object height within two cells, steeper than the wall slope (judged over
   two cells but over 3 m at most: a vertical wall is smeared over two cells, and at
   coarse cells the slope's rise over two cells would exceed every low object; and, where
   two cells span more than those 3 m, more than the terrain's local slope along the profile
   rises over two cells, up to the wall slope's rise over them:
   :func:`.profiles.local_terrain_slopes`, a knoll's flank at 4 m cells) and three
   times steeper than the profile before it: dams, embankments, terrace edges and
   terrain rasterised in steps are not walls), and ends where the profile comes back down
   to the ground extended from the wall's foot at the profile's slope before it, or comes
   down a wall onto ground nearer the foot than the top, or after the largest object
   size. Every wall starts its own run, also inside another one (a run depends on the
   profile within the largest object after its wall only: the objects do not chain along
   a profile beyond the filter's reach). A terrace step is climbed by one scan only;
   objects are kept where both agree. An object is bounded across its profiles too: a run
   with a cell on a cross profile that meets no break, no step of the minimum object height
   and no nodata within twice the largest object is the terrain's (the level between two
   gullies running along Y; :func:`.profiles.bounded_stretches`).
3. **Regions.** Regions enclosed by breaks (4-connected unmarked cells, no larger than
   the largest object, not touching the raster's edge) made mostly of such points become
   whole objects. A region the raster's edge cuts is judged by its walls, as
   ``bareearth:dtm``'s raised regions are (:mod:`..edge_walls`): the runs that met the
   raster's edge, whatever their length (4-connected), form a region that is an object when
   what is seen of it lies within the largest object, more than half of its seen outline
   lies on the walls its runs start from, and those walls, mirrored at every side of the
   raster they meet, run within twice the largest object (a wall cutting off a corner of the
   tile runs twice what is seen: a roof over most of a tile, lidar ``sample_c``; a wall
   running across the tile, three times: a terrace's or a quarry bench's, ground unless
   shorter than two thirds of the largest object). The unmarked regions touching the edge
   made mostly of such an object, and the cells between it and the raster's edge or between
   its parts within the window that stand no lower than it by more than the tolerance (the
   breaks along the edge, where no profile meets a wall), join it.
4. **Final pass** (twice). The ground is interpolated under the objects, the breaks next
   to them and the points with ``|K| >= K_g`` along the X and Y profiles (the straight line
   between the nearest ground on either side, within half the largest object; averaged
   over 3 x 3 cells), so that it depends on the data near a cell only; a cell
   is an object when it stands above that surface by more than the tolerance plus one
   cell of the surface's slope (convex breaks outside objects: half the minimum object
   height more, as the interpolated surface sags a little under convex terrain edges; not
   under concave ones, such as the smeared foot of a wall). Straight
   breaks away from objects (K ~ 0: dams, embankments, terrace edges) are seeds of the
   surface, so terrain edges stay ground, and so are the bowls with ``|K| >= K_g``
   (K > 0, H < 0: gaps between crowns) farther than half a window from the objects and not
   below every cell of the ring around them by more than the tolerance (low points); nearer,
   the bowls between objects (one within half a window on either side along the row or the
   column) at the ground's level (within the tolerance plus the steep slopes' rise over a
   window's diagonal of the lowest cell within a window), below every object cell within half
   a window by half the minimum object height, and not below the surface made without them by
   more than the tolerance (the ground showing between shrubs and crowns, not a smeared foot,
   a roof's hollow beside a higher part or the floor of a pit between its walls), and the lower
   envelope between crowns (under every chord between the cells within ``m`` on either side along the
   row and the column, at the ground's level with the local slope, below every object cell within
   ``m`` by more than the ground's step: on a wooded knoll the ground between crowns is a saddle, no
   bowl). The
   second pass also rests on the bowls that the first found to be ground and not below its
   surface by more than the tolerance. After each pass, a cell above the surface that no
   profile found and that continues a stretch of ground along its X or Y profile (a window's
   independent heights: a window of cells, or of the heights' spacing where longer), beginning
   within two windows, at its own level (within the tolerance plus the rise
   of the terrain's steep slopes over their distance) and joined to it by steps no higher than
   the tolerance plus that rise over a cell, is ground: the surface spans a terrace's or a
   quarry bench's wall with a straight line that sags metres under its top edge. Nodata takes
   the height of the nearest ground seed rather than being spanned by the surface (the surface
   then depends on the ground near a cell, not on the far side of a nodata area). A concave
   break deeper than the minimum object height below the surface and below every cell of the
   ring around it is a low blunder (code 2): a pit, not a valley or a cut.

The package's files follow these steps: :mod:`.derivatives` (the local fit, K and H, the
breaks: steps 1-2), :mod:`.profiles` (profile scans and enclosed regions: steps 3-4),
:mod:`.ground` (the final pass against the ground surface: step 5) and :mod:`.method`
(:func:`filter_curvature`, the parameters, the halo and :data:`METHOD`).

Reference
---------
Luong Chinh Ke (2002). Filtering of DSM for generating DTM (local trend and Gaussian
curvature, section 2.2). The curvature formulas are those of differential geometry of a
graph surface (e.g. Evans 1980; Zevenbergen & Thorne 1987).
"""
from .derivatives import MODELS, compute_curvature, curvatures_from_derivatives, local_derivatives
from .method import (
    METHOD,
    OBJECT_SIZE_M,
    bend_noise_gain,
    curvature_halo,
    derive_k_g,
    edge_bend,
    filter_curvature,
    object_size,
    resolve_curvature_params,
)

__all__ = ["METHOD", "MODELS", "OBJECT_SIZE_M", "bend_noise_gain", "compute_curvature", "curvature_halo",
           "curvatures_from_derivatives", "derive_k_g", "edge_bend", "filter_curvature", "local_derivatives",
           "object_size", "resolve_curvature_params"]
