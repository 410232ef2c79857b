"""Small synthetic surfaces shared by the tests (plain functions; pytest puts ``tests/`` on the path)."""
import numpy as np


def grid(n):
    """Row and column coordinates (float32) of an ``n`` x ``n`` grid."""
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    return y, x


def noisy(ground, seed=0, sd=0.03):
    """``ground`` plus Gaussian noise of ``sd`` (seeded), as float32."""
    rng = np.random.default_rng(seed)
    return (ground + rng.normal(0.0, sd, ground.shape)).astype(np.float32)


def in_blocks(fn, shape, block, halo):
    """``fn`` run block by block: each ``block`` x ``block`` block read with ``halo`` cells around it.

    ``fn(rows, cols)`` gets the slices of the read window and returns its result (same shape);
    the block's part of it is pasted into the whole. Equals ``fn`` on the whole raster when
    ``halo`` covers everything a cell's result depends on (the contract of blocked runs).
    """
    n_rows, n_cols = shape
    out = None
    for r in range(0, n_rows, block):
        for c in range(0, n_cols, block):
            wr = slice(max(r - halo, 0), min(r + block + halo, n_rows))
            wc = slice(max(c - halo, 0), min(c + block + halo, n_cols))
            part = fn(wr, wc)
            if out is None:
                out = np.zeros(shape, part.dtype)
            out[r:r + block, c:c + block] = part[r - wr.start:r - wr.start + block, c - wc.start:c - wc.start + block]
    return out


def raised_ground(kind, n=300):
    """Bare ground raised above a gentle plane (1 m cells, ``n`` x ``n``, no noise) that no filter may
    take for a roof: ``terrace`` (a 4 m wall across the raster), ``plateau`` (60 degree sides, 20 m high,
    160 m top), ``embankment`` (a dam, 1:1.5 banks, 6 m high), ``hilltop`` (45 degree sides to a flat
    top), ``hilltop30`` (the same, top 30 m wide), ``steep plateau`` (75 degree sides, 20 m high, 5 m
    wide)."""
    y, x = grid(n)
    c = n / 2
    r = np.hypot(x - c, y - c)
    raised = {
        "terrace": np.where(x > c, 4.0, 0.0),
        "plateau": np.clip((100 - r) * 1.73, 0, 20),
        "embankment": np.clip((30 - np.abs(y - c)) / 1.5, 0, 6),
        "hilltop": np.clip((100 - r) * 1.0, 0, 20),
        "hilltop30": np.clip((35 - r) * 1.0, 0, 20),
        "steep plateau": np.clip((100 - r) * 3.73, 0, 20),
    }[kind]
    return 50 + 0.02 * x + 0.01 * y + raised


def level_off_a_corner(cell, kind="roof"):
    """As lidar/sample_c: an 88 x 76 m tile at ``cell`` metres whose upper level covers about 74 % of it,
    cut by the tile's edges on three sides, its one edge a diagonal from the top side (48 m from the
    left) to the left side 2 m above the bottom (next to the corner at coarse cells), a wedge of gentle
    ground (rising 2.6 m across the tile) in the top-left corner beyond it. ``kind``: ``roof`` (a flat
    roof 25 m high on a vertical wall) or ``terrace`` (bare ground 6 m higher, joined to the wedge by a
    bank 12 m wide: 27 degrees). Returns ``(z, upper)``: the surface (5 cm noise) and the upper level's
    cells (for the terrace: its top, beyond the bank)."""
    rows, cols = int(round(76 / cell)), int(round(88 / cell))
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    x, y = (x + 0.5) * cell, (y + 0.5) * cell
    ground = 30 + 0.02 * x + 0.01 * y
    # distance beyond the diagonal edge, metres (positive on the upper level)
    d = (x / 48 + y / 74 - 1) / np.hypot(1 / 48, 1 / 74)
    if kind == "roof":
        upper = d > 0
        z = np.where(upper, 55.0, ground)
    else:
        z = ground + 6.0 * np.clip(d / 12.0, 0.0, 1.0)
        upper = d > 12
    return noisy(z, sd=0.05), upper
