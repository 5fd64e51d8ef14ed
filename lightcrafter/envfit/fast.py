"""Fast solver: the objective of :mod:`.model` on precomputed sparse transport (:mod:`.transport`).

Set-up traces each fitted frame's transport once (``transport_pixels`` pixels sampled uniformly
from its used pixels, ``transport_spp`` lanes each); an iteration then costs one sparse product
(scipy CSR, float32) and its transpose for the gradient, wrapped as a torch autograd function, plus
the map head and TV in torch. Same tonemap, L1, TV, frame sequence, Adam and parameters as the
reference solver; the pixels (and Monte Carlo samples) are a fixed sample instead of fresh ones.

The sparse products run in scipy (``csr_matvec`` and its transpose, float32) inside a torch
autograd function: torch's own CPU CSR product measured about 8x slower on these matrices. The
loss and its gradient with respect to the predicted pixels are formed in numpy in the same call,
so an iteration is two sparse products plus the map head, TV and Adam in torch (single thread).
Deterministic: same inputs and seed give bit-identical fits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .model import ExternalLoss, l1_tonemapped, l1_tonemapped_np, reinhard
from .transport import Transport, build_transport, sample_pixels


class _TransportProduct(torch.autograd.Function):
    @staticmethod
    def forward(ctx, env: torch.Tensor, transport: Transport) -> torch.Tensor:  # env (H, W, 3)
        ctx.transport = transport
        ctx.env_shape = tuple(env.shape)
        out = transport.apply(env.detach().numpy())
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        g = ctx.transport.apply_transpose(grad.detach().numpy())
        return torch.from_numpy(g).reshape(ctx.env_shape), None


def transport_render(env: torch.Tensor, transport: Transport) -> torch.Tensor:
    """Differentiable (P, 3) radiance of the transport's pixels under ``env`` (H, W, 3)."""
    return _TransportProduct.apply(env, transport)


class FastObjective:
    """Data term of :mod:`.model` on one transport per fitted frame."""

    def __init__(self, transports: dict[int, Transport], observed_tm: dict[int, torch.Tensor]):
        self.transports = transports
        self.observed_tm = observed_tm
        self.observed_np = {k: v.numpy().astype(np.float64) for k, v in observed_tm.items()}

    def data_loss(self, env: torch.Tensor, frame: int, iteration: int) -> torch.Tensor:
        """Mean |T(T_f env) - T(I_f)| over the frame's sampled pixels and channels; its gradient is
        formed in numpy (one transposed product), fewer small torch operations per iteration."""
        transport, obs = self.transports[frame], self.observed_np[frame]

        def fn(env_np):
            loss, g_pred = l1_tonemapped_np(transport.apply(env_np), obs)
            return loss, transport.apply_transpose(g_pred)

        return ExternalLoss.apply(env, fn)

    def data_loss_autograd(self, env: torch.Tensor, frame: int) -> torch.Tensor:
        """The same value through torch autograd (tests compare the two)."""
        pred = transport_render(env, self.transports[frame])
        return l1_tonemapped(pred, self.observed_tm[frame])

    @property
    def nbytes(self) -> int:
        seen, total = set(), 0
        for t in self.transports.values():
            if id(t) not in seen:
                seen.add(id(t))
                total += t.nbytes
        return total

    @property
    def nnz(self) -> int:
        seen, total = set(), 0
        for t in self.transports.values():
            if id(t) not in seen:
                seen.add(id(t))
                total += t.nnz
        return total


def sample_key(view) -> tuple:
    """What seeds a view's pixel sample: the file name of its buffers, K and c2w, not the folder the clip lies
    in, so the same clip gives the same fit from any results folder (relative or absolute path)."""
    return (Path(view.key).name, *view.cache_key()[1:])


def build_fast_objective(tracer, views, video, pixels: int, spp: int, seed: int, env_height: int,
                         env_width: int) -> FastObjective:
    """Trace the transport of every fitted frame (frames with one view and one pixel sample share it)."""
    transports: dict[int, Transport] = {}
    observed: dict[int, torch.Tensor] = {}
    shared: dict = {}
    for i in video.fitted:
        view = views[i]
        px = sample_pixels(video.used[i], pixels, seed, sample_key(view))
        key = (view.cache_key(), px.tobytes())
        if key not in shared:
            shared[key] = build_transport(tracer, view, px, spp, seed=seed * 7919 + i, env_height=env_height,
                                          env_width=env_width)
        transports[i] = shared[key]
        obs = video.frames[i].reshape(-1, 3)[px]
        observed[i] = torch.from_numpy(reinhard(obs.astype(np.float32)))
    return FastObjective(transports, observed)
