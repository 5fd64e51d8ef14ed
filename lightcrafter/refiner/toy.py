"""Generated toy pairs for tests and benchmarks (no pipeline data needed).

A target clip is a smooth gradient background with a few moving soft discs and a faint moving
texture; its proxy is the same clip with PBR-proxy-like artifacts: a colour/exposure offset, a
per-frame flicker and jagged (block-quantised) edges. Values are display-space in [-1, 1],
shaped (3, N, H, W). Pure function of the seed.
"""

from __future__ import annotations

import torch


def toy_pair(seed: int, num_frames: int = 9, height: int = 32, width: int = 48, stress: bool = False) -> dict:
    """``stress=True`` adds a sharp moving checker (period 8-12 px) and per-pixel noise (sigma 0.02),
    a stress case for the patch autoencoder that resembles a low-spp render of a checker ground."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    base = torch.rand(3, 1, 1, generator=g) * 0.6 + 0.2
    grad = torch.rand(3, 1, 1, generator=g) * 0.4 - 0.2
    frames, proxies = [], []
    n_disc = 3
    pos = torch.rand(n_disc, 2, generator=g)
    vel = (torch.rand(n_disc, 2, generator=g) - 0.5) * 0.06
    col = torch.rand(n_disc, 3, generator=g)
    rad = torch.rand(n_disc, generator=g) * 0.12 + 0.08
    flick = torch.randn(num_frames, generator=g) * 0.04
    shift = torch.rand(3, 1, 1, generator=g) * 0.16 - 0.08
    for f in range(num_frames):
        img = base + grad * (xx + yy)[None]
        img = img + 0.03 * torch.sin(40 * (xx + 0.01 * f))[None]
        if stress:
            per = 8 + 4 * float(base.mean())
            chk = ((((xx * width + 0.7 * f) // per) + ((yy * height) // per)) % 2)[None]
            img = img + 0.25 * (chk - 0.5) + 0.02 * torch.randn(img.shape, generator=g)
        hard = img.clone()
        for d in range(n_disc):
            p = (pos[d] + vel[d] * f) % 1.0  # wraps around so long clips stay populated
            dist = ((xx - p[0]) ** 2 + (yy - p[1]) ** 2).sqrt()
            soft = torch.sigmoid((rad[d] - dist) * 60)[None]
            qx, qy = (xx * width / 4).floor() * 4 / width, (yy * height / 4).floor() * 4 / height
            jag = (((qx - p[0]) ** 2 + (qy - p[1]) ** 2).sqrt() < rad[d]).float()[None]
            img = img * (1 - soft) + col[d].view(3, 1, 1) * soft
            hard = hard * (1 - jag) + col[d].view(3, 1, 1) * jag
        frames.append(img)
        proxies.append(hard + shift + flick[f])
    tgt = torch.stack(frames, 1).clamp(0, 1) * 2 - 1
    prx = torch.stack(proxies, 1).clamp(0, 1) * 2 - 1
    return {"pair_id": f"toy{seed:04d}", "proxy": prx.float(), "target": tgt.float()}


class ToyDataset:
    def __init__(self, n: int, seed0: int = 0, **kw):
        self.items = [toy_pair(seed0 + i, **kw) for i in range(n)]

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]
