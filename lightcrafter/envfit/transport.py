"""Sparse light-transport matrices: R's environment term on a fixed pixel sample, traced once.

With geometry and materials fixed, R's pixel radiance is linear in the map's texels::

    R_p,c(L) = sum_t T_c[p, t] L[t, c]        (p: sampled pixel, t: texel row * We + col, c: R, G, B)

:func:`build_transport` traces ``spp`` lanes per pixel with :class:`~.tracing.Tracer` (map
independent, visibility included) and accumulates each lane's RGB weight / spp, split over the
four bilinear taps of its direction, into ``T``. Equal (pixel, texel) entries are summed, so a row
holds at most min(4 spp, He We) entries. ``T[p] . L`` is then exactly the sample mean the tracer
would give with these lanes (same expectation as R); the products run in scipy (CSR, float32).

Memory (bytes) of the matrices of F_s fitted frames of P_s sampled pixels each::

    M = sum_f [ nnz_f (4 + 3 * 4) + 4 (P_f + 1) ]  <=  F_s P_s (16 min(4 spp, He We) + 4) + 4 F_s

(one int32 column index shared by three float32 channel values, plus int32 row pointers);
frames that share a view and a pixel sample (static camera) share one matrix.
:func:`memory_bound_bytes` evaluates the bound; :attr:`Transport.nbytes` measures.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from lightcrafter.clip import FrameView

from .tracing import Tracer, bilinear_taps


def memory_bound_bytes(frames: int, pixels: int, spp: int, env_height: int = 64, env_width: int = 128) -> int:
    """Upper bound of the matrices' memory (module doc formula)."""
    return int(frames * pixels * (16 * min(4 * spp, env_height * env_width) + 4) + 4 * frames)


@dataclass
class Transport:
    """One frame's transport: three CSR matrices (P x He We, float32) sharing their index arrays,
    and the flat image index of each row's pixel."""

    mats: list
    pixels: np.ndarray

    @property
    def nnz(self) -> int:
        return int(self.mats[0].nnz)

    @property
    def nbytes(self) -> int:
        m = self.mats[0]
        return int(m.indices.nbytes + m.indptr.nbytes + sum(x.data.nbytes for x in self.mats))

    def apply(self, env: np.ndarray) -> np.ndarray:
        """(P, 3) radiance of the sampled pixels under a (He We, 3) (or (He, We, 3)) map."""
        env = np.asarray(env, np.float32).reshape(-1, 3)
        return np.stack([m @ env[:, c] for c, m in enumerate(self.mats)], axis=-1)

    def apply_transpose(self, grad: np.ndarray) -> np.ndarray:
        """(He We, 3) = T^T grad for a (P, 3) ``grad``."""
        grad = np.asarray(grad, np.float32)
        return np.stack([m.T @ grad[:, c] for c, m in enumerate(self.mats)], axis=-1)


def build_transport(tracer: Tracer, view: FrameView, pixels: np.ndarray, spp: int, seed: int,
                    env_height: int = 64, env_width: int = 128, max_lanes: int = 1 << 20) -> Transport:
    """Trace and accumulate the transport of ``pixels`` (flat indices) of ``view`` (module doc)."""
    pixels = np.asarray(pixels, np.int64)
    n_tex = env_height * env_width
    spp_eff = None
    rows_all, cols_all, vals_all = [], [], []
    per = max(1, max_lanes // max(1, spp))
    for k, start in enumerate(range(0, len(pixels), per)):
        chunk = pixels[start:start + per]
        lanes = tracer.lanes(view, chunk, spp, seed=(seed * 1000003 + k) % (1 << 32))
        spp_eff = lanes.spp
        d = np.stack([np.asarray(lanes.d.x), np.asarray(lanes.d.y), np.asarray(lanes.d.z)], -1).astype(np.float64)
        w = np.stack([np.asarray(lanes.w.x), np.asarray(lanes.w.y), np.asarray(lanes.w.z)], -1).astype(np.float64)
        live = np.flatnonzero((w != 0).any(-1))
        if not len(live):
            continue
        idx, bw = bilinear_taps(d[live], env_height, env_width)  # (n, 4)
        row = (start + live // lanes.spp).astype(np.int64)
        vals = w[live][:, None, :] * bw[..., None] / lanes.spp  # (n, 4, 3)
        keep = bw.ravel() > 0
        rows_all.append(np.repeat(row, 4)[keep])
        cols_all.append(idx.ravel()[keep])
        vals_all.append(vals.reshape(-1, 3)[keep])
        # coalesce per chunk to bound memory
        key = rows_all[-1] * n_tex + cols_all[-1]
        uk, inv = np.unique(key, return_inverse=True)
        summed = np.stack([np.bincount(inv, vals_all[-1][:, c], len(uk)) for c in range(3)], -1)
        rows_all[-1], cols_all[-1], vals_all[-1] = uk // n_tex, uk % n_tex, summed
    n = len(pixels)
    if rows_all:
        rows = np.concatenate(rows_all)
        cols = np.concatenate(cols_all)
        vals = np.concatenate(vals_all)
    else:
        rows = cols = np.zeros(0, np.int64)
        vals = np.zeros((0, 3))
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    indices = cols.astype(np.int32)
    indptr = indptr.astype(np.int32)
    mats = [sp.csr_matrix((vals[:, c].astype(np.float32), indices, indptr), shape=(n, n_tex), copy=False)
            for c in range(3)]
    for m in mats[1:]:  # share the index arrays (scipy may have copied them)
        m.indices, m.indptr = mats[0].indices, mats[0].indptr
    return Transport(mats=mats, pixels=pixels)


def sample_pixels(used: np.ndarray, count: int, seed: int, view_key) -> np.ndarray:
    """A uniform sample (without replacement, sorted) of ``count`` of the ``used`` pixels; all of them
    when ``count <= 0`` or there are fewer. Seeded by (seed, view key): frames of one static view with
    the same used pixels get the same sample (and can share one matrix)."""
    used = np.asarray(used, np.int64)
    if count <= 0 or count >= len(used):
        return used.copy()
    h = hashlib.sha256(repr((int(seed), view_key)).encode() + used.tobytes()).digest()
    rng = np.random.default_rng(int.from_bytes(h[:8], "little"))
    return np.sort(rng.choice(used, size=int(count), replace=False))
