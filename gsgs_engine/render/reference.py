"""Pure-torch reference rasteriser: the oracle that defines the semantics every backend matches.

Vectorised over 16x16 tiles: each chunk of tiles is blended against only the Gaussians
binned to it, padded to a common list length. Front-to-back compositing is a cumulative
product; the per-pixel early stop (3DGS: a Gaussian that would push T below 1e-4 is not
added, and nothing after it) becomes a prefix mask computed without gradient. Each chunk
keeps only its inputs and is recomputed in the backward pass (activation checkpointing), so
memory stays bounded by one chunk in both passes. Works in float32 and float64.
"""

from __future__ import annotations

import torch

TILE_SIZE = 16
PIXELS_PER_TILE = TILE_SIZE * TILE_SIZE
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
DEFAULT_MAX_ELEMENTS = 1 << 19  # pixels x Gaussians per chunk: small chunks stay in cache (measured fastest)


def bin_gaussians(means2d: torch.Tensor, radii: torch.Tensor, depths: torch.Tensor, width: int, height: int):
    """Tile intersections sorted by (tile, depth, Gaussian index).

    Gaussian i touches tiles floor((m - r) / 16) .. floor((m + r) / 16) in x and y, clipped to
    the grid. Returns (gauss_ids [M] int64, tile_starts [n_tiles], tile_counts [n_tiles]).
    """
    device = means2d.device
    gx = (width + TILE_SIZE - 1) // TILE_SIZE
    gy = (height + TILE_SIZE - 1) // TILE_SIZE
    n_tiles = gx * gy
    with torch.no_grad():
        active = torch.nonzero(radii > 0).squeeze(1)
        if active.numel() == 0:
            empty = torch.zeros(0, dtype=torch.long, device=device)
            zeros = torch.zeros(n_tiles, dtype=torch.long, device=device)
            return empty, zeros, zeros
        # Depth order with ties broken by index: a stable sort of index-ordered ids.
        order = torch.sort(depths.detach()[active], stable=True).indices
        ids = active[order]
        m = means2d.detach()[ids].double()
        r = radii[ids].double()
        # Clamp before the integer cast so huge radii cannot overflow.
        x0 = torch.floor((m[:, 0] - r) / TILE_SIZE).clamp(0, gx - 1).long()
        x1 = torch.floor((m[:, 0] + r) / TILE_SIZE).clamp(-1, gx - 1).long()
        y0 = torch.floor((m[:, 1] - r) / TILE_SIZE).clamp(0, gy - 1).long()
        y1 = torch.floor((m[:, 1] + r) / TILE_SIZE).clamp(-1, gy - 1).long()
        nx = (x1 - x0 + 1).clamp_min(0)
        ny = (y1 - y0 + 1).clamp_min(0)
        counts = nx * ny
        total = int(counts.sum())
        pair_owner = torch.repeat_interleave(torch.arange(ids.numel(), device=device), counts)
        first = torch.cumsum(counts, 0) - counts
        local = torch.arange(total, device=device) - first[pair_owner]
        nx_p = nx[pair_owner]
        tile_ids = (y0[pair_owner] + local // nx_p) * gx + x0[pair_owner] + local % nx_p
        # Stable sort by tile keeps the depth (then index) order inside each tile.
        tile_order = torch.sort(tile_ids, stable=True).indices
        gauss_ids = ids[pair_owner[tile_order]]
        tile_counts = torch.bincount(tile_ids, minlength=n_tiles)
        tile_starts = torch.cumsum(tile_counts, 0) - tile_counts
    return gauss_ids, tile_starts, tile_counts


def _exclusive_cumprod(x: torch.Tensor) -> torch.Tensor:
    ones = torch.ones_like(x[..., :1])
    return torch.cumprod(torch.cat([ones, x[..., :-1]], dim=-1), dim=-1)


def _blend_block(T_in, done_in, px, py, means2d, conics, colors, opacities, depths, valid):
    """Composite one block of depth-sorted Gaussians onto a block of pixels.

    Shapes: pixels [n, P], Gaussians [n, K, ...]. Returns colour [n, P, 3], depth [n, P],
    T_out [n, P], done_out [n, P] (the early stop already happened).
    """
    dx = means2d[:, None, :, 0] - px[:, :, None]  # [n, P, K]
    dy = means2d[:, None, :, 1] - py[:, :, None]
    A, B, C = (conics[:, None, :, i] for i in range(3))
    power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
    # clamp(max=0) keeps exp finite for skipped entries, so their zero gradient stays zero.
    alpha = (opacities[:, None, :] * torch.exp(power.clamp(max=0.0))).clamp(max=ALPHA_MAX)
    used = valid[:, None, :] & (power <= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(used, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        T_after = T_in[..., None] * torch.cumprod(1.0 - alpha, dim=-1)
        stop = used & (T_after < T_MIN)  # prefix property: T_after never increases along K
        included = (~stop) & (~done_in[..., None])
        done_out = done_in | stop.any(-1)
    alpha = alpha * included
    one_minus = 1.0 - alpha
    T = T_in[..., None] * _exclusive_cumprod(one_minus)
    weights = alpha * T  # alpha_i T_i (eq. 3)
    color = torch.bmm(weights, colors)
    depth = torch.bmm(weights, depths[..., None])[..., 0]  # sum d_i alpha_i T_i (eq. 7)
    T_out = T[..., -1] * one_minus[..., -1]
    return color, depth, T_out, done_out


class _RecomputedBlend(torch.autograd.Function):
    """_blend_block that saves only its inputs and recomputes its graph in backward.

    (torch.utils.checkpoint would do the same, but its first use imports sympy and friends,
    which costs seconds per process.)
    """

    @staticmethod
    def forward(ctx, T_in, done_in, px, py, means2d, conics, colors, opacities, depths, valid):
        ctx.save_for_backward(T_in, done_in, px, py, means2d, conics, colors, opacities, depths, valid)
        with torch.no_grad():
            color, depth, T_out, done_out = _blend_block(T_in, done_in, px, py, means2d, conics, colors, opacities,
                                                         depths, valid)
        ctx.mark_non_differentiable(done_out)
        return color, depth, T_out, done_out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_color, grad_depth, grad_T, _grad_done):
        saved = ctx.saved_tensors
        wanted = [i for i, need in enumerate(ctx.needs_input_grad) if need]
        inputs = [x.detach().requires_grad_(i in wanted) for i, x in enumerate(saved)]
        with torch.enable_grad():
            color, depth, T_out, _ = _blend_block(*inputs)
        outputs, grads_out = [], []
        for out, g in ((color, grad_color), (depth, grad_depth), (T_out, grad_T)):
            if g is not None:
                outputs.append(out)
                grads_out.append(g)
        grads = [None] * len(saved)
        if wanted and outputs:
            found = torch.autograd.grad(outputs, [inputs[i] for i in wanted], grads_out, allow_unused=True)
            for i, g in zip(wanted, found):
                grads[i] = g
        return tuple(grads)


def rasterize_reference(means2d: torch.Tensor, conics: torch.Tensor, colors: torch.Tensor, opacities: torch.Tensor,
                        depths: torch.Tensor, radii: torch.Tensor, width: int, height: int,
                        background: torch.Tensor, max_elements: int = DEFAULT_MAX_ELEMENTS):
    """Alpha-composite projected Gaussians -> (color [H, W, 3], depth [H, W], alpha [H, W]).

    `max_elements` bounds pixels x Gaussians evaluated at once (memory of one chunk).
    """
    dtype, device = means2d.dtype, means2d.device
    gx = (width + TILE_SIZE - 1) // TILE_SIZE
    gy = (height + TILE_SIZE - 1) // TILE_SIZE
    n_tiles = gx * gy
    channels = colors.shape[-1]
    gauss_ids, tile_starts, tile_counts = bin_gaussians(means2d, radii, depths, width, height)

    local = torch.arange(PIXELS_PER_TILE, device=device)
    local_x = (local % TILE_SIZE).to(dtype) + 0.5
    local_y = (local // TILE_SIZE).to(dtype) + 0.5

    needs_grad = torch.is_grad_enabled() and any(
        t.requires_grad for t in (means2d, conics, colors, opacities, depths))
    busy = torch.nonzero(tile_counts > 0).squeeze(1)
    busy = busy[torch.sort(tile_counts[busy], descending=True, stable=True).indices]
    busy_counts = tile_counts[busy].tolist()
    out_tiles, out_color, out_depth, out_T = [], [], [], []
    i = 0
    while i < len(busy_counts):
        k_max = busy_counts[i]  # tiles are sorted by count, so the first is the longest
        n = max(1, min(len(busy_counts) - i, max_elements // (PIXELS_PER_TILE * k_max)))
        tiles = busy[i:i + n]
        i += n
        k_block = max(1, max_elements // (PIXELS_PER_TILE * n))
        starts, counts = tile_starts[tiles], tile_counts[tiles]
        px = ((tiles % gx) * TILE_SIZE).to(dtype)[:, None] + local_x
        py = ((tiles // gx) * TILE_SIZE).to(dtype)[:, None] + local_y
        T = torch.ones(n, PIXELS_PER_TILE, dtype=dtype, device=device)
        done = torch.zeros(n, PIXELS_PER_TILE, dtype=torch.bool, device=device)
        color = torch.zeros(n, PIXELS_PER_TILE, channels, dtype=dtype, device=device)
        depth = torch.zeros(n, PIXELS_PER_TILE, dtype=dtype, device=device)
        for k0 in range(0, k_max, k_block):
            if bool(done.all()):
                break
            k = torch.arange(k0, min(k_max, k0 + k_block), device=device)
            valid = k[None, :] < counts[:, None]
            slot = torch.where(valid, starts[:, None] + k[None, :], torch.zeros_like(valid, dtype=torch.long))
            g = gauss_ids[slot]
            args = (T, done, px, py, means2d[g], conics[g], colors[g], opacities[g], depths[g], valid)
            if needs_grad:
                c, d, T, done = _RecomputedBlend.apply(*args)
            else:
                c, d, T, done = _blend_block(*args)
            color = color + c
            depth = depth + d
        out_tiles.append(tiles)
        out_color.append(color)
        out_depth.append(depth)
        out_T.append(T)

    full_color = torch.zeros(n_tiles, PIXELS_PER_TILE, channels, dtype=dtype, device=device)
    full_depth = torch.zeros(n_tiles, PIXELS_PER_TILE, dtype=dtype, device=device)
    full_T = torch.ones(n_tiles, PIXELS_PER_TILE, dtype=dtype, device=device)
    if out_tiles:
        tiles = torch.cat(out_tiles)
        full_color = full_color.index_copy(0, tiles, torch.cat(out_color))
        full_depth = full_depth.index_copy(0, tiles, torch.cat(out_depth))
        full_T = full_T.index_copy(0, tiles, torch.cat(out_T))

    def to_image(x: torch.Tensor) -> torch.Tensor:
        x = x.reshape(gy, gx, TILE_SIZE, TILE_SIZE, *x.shape[2:]).transpose(1, 2)
        return x.reshape(gy * TILE_SIZE, gx * TILE_SIZE, *x.shape[4:])[:height, :width]

    T_img = to_image(full_T)
    color_img = to_image(full_color) + T_img[..., None] * background.to(dtype)
    return color_img, to_image(full_depth), 1.0 - T_img
