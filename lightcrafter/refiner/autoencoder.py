"""Latent spaces of the refiner. Layout convention everywhere in this package:

* pixel video: ``(B, 3, N, H, W)`` display values in [-1, 1] (``2 * linear_to_display - 1``);
* latent video: ``(B, F, C, h, w)`` -- the transformer's layout -- with F = (N - 1) / 4 + 1,
  h = H / 8, w = W / 8.

:class:`DCTPatchAutoencoder` (``tiny``) has CogVideoX's shape semantics without training: colours
are rotated to an orthonormal opponent basis (luma (R+G+B)/sqrt3, chroma (R-G)/sqrt2 and
(R+G-2B)/sqrt6), then each block of 4 frames x 8 x 8 pixels of each opponent channel is projected
on its lowest-frequency orthonormal 3-D DCT-II basis functions (``coeffs`` = how many per opponent
channel, e.g. [32, 8, 8]: chroma needs fewer); the first frame is causal (it alone forms latent frame 0, replicated 4x in
time so only the temporal-DC coefficients are non-zero). Decoding is the transpose projection, so
it is exact for the kept frequencies and lossless when all 256 coefficients are kept.
Per-channel shift/scale (fitted on training targets by :meth:`fit_normalisation`) bring latents to
roughly unit variance (``normalisation="channel"``), or one scale for every channel brings them to
unit variance on average (``"global"``, like the CogVideoX VAE's single scaling factor). With the
global scale the transform stays orthogonal up to one factor, so a latent L2 distance is the pixel
L2 distance (of the kept frequencies) times a constant and diffusion noise is white in pixel space;
per-channel scaling instead weights the low-energy high-frequency coefficients up (in a
v-MSE or L2 loss) by the inverse of their variance.

:class:`CogVideoXVAE` (``paper``) wraps ``AutoencoderKLCogVideoX`` from a local path; it encodes with
the posterior mode (deterministic, so target latents can be cached exactly) and multiplies by the
VAE's ``scaling_factor`` (0.7 for CogVideoX-5B).
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from .frames import check_frames

BLOCK_T, BLOCK_S = 4, 8


def _dct_matrix(n: int) -> torch.Tensor:
    """Orthonormal DCT-II matrix (rows = frequencies) of size n x n, float64."""
    k = torch.arange(n, dtype=torch.float64)[:, None]
    i = torch.arange(n, dtype=torch.float64)[None, :]
    m = torch.cos(math.pi * (i + 0.5) * k / n) * math.sqrt(2.0 / n)
    m[0] /= math.sqrt(2.0)
    return m


def dct_basis(keep: int) -> torch.Tensor:
    """(256, keep) orthonormal columns: the ``keep`` lowest-frequency 4x8x8 DCT basis vectors.

    Frequencies are ordered by normalised radius (ft/4)^2 + (fy/8)^2 + (fx/8)^2, ties by index.
    """
    if not 1 <= keep <= BLOCK_T * BLOCK_S * BLOCK_S:
        raise ValueError(f"autoencoder coefficients per channel = {keep}: must be in [1, 256]")
    dt, ds = _dct_matrix(BLOCK_T), _dct_matrix(BLOCK_S)
    full = torch.einsum("at,by,cx->abctyx", dt, ds, ds).reshape(256, 256)  # rows: (ft, fy, fx)
    ft, fy, fx = torch.meshgrid(torch.arange(4.0), torch.arange(8.0), torch.arange(8.0), indexing="ij")
    radius = ((ft / 4) ** 2 + (fy / 8) ** 2 + (fx / 8) ** 2).reshape(-1)
    order = sorted(range(256), key=lambda j: (float(radius[j]), j))[:keep]
    return full[order].T.contiguous().float()


OPPONENT = torch.tensor(
    [[1 / math.sqrt(3)] * 3, [1 / math.sqrt(2), -1 / math.sqrt(2), 0.0], [1 / math.sqrt(6), 1 / math.sqrt(6), -2 / math.sqrt(6)]]
)  # rows: luma, chroma1, chroma2 (orthonormal, so the inverse is the transpose)


class DCTPatchAutoencoder(nn.Module):
    """Fixed linear 8x-spatial / 4x-temporal causal patch autoencoder (see module docstring).

    ``coeffs``: int (same for the 3 opponent channels) or [luma, chroma1, chroma2]; 256 each = lossless.
    """

    scale_spatial = BLOCK_S
    scale_temporal = BLOCK_T

    def __init__(self, coeffs=(32, 8, 8), normalisation: str = "channel"):
        super().__init__()
        if normalisation not in ("channel", "global"):
            raise ValueError(f"normalisation={normalisation!r}: use 'channel' or 'global'")
        self.normalisation = normalisation
        self.keeps = [int(coeffs)] * 3 if isinstance(coeffs, (int, float)) else [int(c) for c in coeffs]
        if len(self.keeps) != 3:
            raise ValueError(f"coeffs={coeffs!r}: give one int or three (luma, chroma1, chroma2)")
        self.kmax = max(self.keeps)
        self.register_buffer("basis", dct_basis(self.kmax), persistent=False)
        sel = torch.cat([torch.arange(k) + i * self.kmax for i, k in enumerate(self.keeps)])
        self.register_buffer("select", sel, persistent=False)  # kept entries of the (3, kmax) coefficients
        self.register_buffer("colour", OPPONENT.clone(), persistent=False)
        self.register_buffer("shift", torch.zeros(len(sel)))
        self.register_buffer("scale", torch.ones(len(sel)))

    @property
    def latent_channels(self) -> int:
        return int(sum(self.keeps))

    def _check(self, video: torch.Tensor) -> None:
        if video.ndim != 5 or video.shape[1] != 3:
            raise ValueError(f"expected (B, 3, N, H, W) video, got {tuple(video.shape)}")
        check_frames(video.shape[2])
        if video.shape[3] % 16 or video.shape[4] % 16:
            raise ValueError(f"H x W = {video.shape[3]}x{video.shape[4]}: must be multiples of 16 (8x VAE, 2x patch)")

    def encode_raw(self, video: torch.Tensor) -> torch.Tensor:
        self._check(video)
        video = torch.einsum("oc,bcnhw->bonhw", self.colour.to(video.dtype), video)
        return self._project(torch.cat([video[:, :, :1].expand(-1, -1, BLOCK_T, -1, -1), video[:, :, 1:]], dim=2))

    def encode_blocks(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 3, 4f, H, W) -> un-normalised latent (B, f, C, h, w): every 4 frames one latent frame, none causal
        (:meth:`encode_raw` is this after repeating frame 0 to a block of its own)."""
        return self._project(torch.einsum("oc,bcnhw->bonhw", self.colour.to(x.dtype), x))

    def _project(self, x: torch.Tensor) -> torch.Tensor:
        """Opponent-colour blocks (B, 3, 4f, H, W) -> their kept DCT coefficients (B, f, C, h, w)."""
        b, _, n, hh, ww = x.shape
        f, h, w = n // BLOCK_T, hh // BLOCK_S, ww // BLOCK_S
        x = x.reshape(b, 3, f, BLOCK_T, h, BLOCK_S, w, BLOCK_S).permute(0, 2, 1, 4, 6, 3, 5, 7)
        coef = x.reshape(b, f, 3, h, w, 256) @ self.basis.to(x.dtype)  # (b, f, 3, h, w, kmax)
        coef = coef.permute(0, 1, 2, 5, 3, 4).reshape(b, f, 3 * self.kmax, h, w)
        return coef[:, :, self.select]

    def decode_raw(self, lat: torch.Tensor) -> torch.Tensor:
        x = self._unproject(lat)
        first = x[:, :, :BLOCK_T].mean(dim=2, keepdim=True)  # least-squares estimate of frame 0
        x = torch.cat([first, x[:, :, BLOCK_T:]], dim=2)
        return torch.einsum("oc,bonhw->bcnhw", self.colour.to(x.dtype), x)

    def decode_blocks(self, lat: torch.Tensor) -> torch.Tensor:
        """Un-normalised latent (B, f, C, h, w) -> (B, 3, 4f, H, W): each latent frame's block of 4 frames, latent
        frame 0 too (the transpose of :meth:`encode_blocks`)."""
        x = self._unproject(lat)
        return torch.einsum("oc,bonhw->bcnhw", self.colour.to(x.dtype), x)

    def _unproject(self, lat: torch.Tensor) -> torch.Tensor:
        """Kept DCT coefficients (B, f, C, h, w) -> opponent-colour blocks (B, 3, 4f, H, W)."""
        b, f, c, h, w = lat.shape
        full = lat.new_zeros(b, f, 3 * self.kmax, h, w)
        full[:, :, self.select] = lat
        coef = full.reshape(b, f, 3, self.kmax, h, w).permute(0, 1, 2, 4, 5, 3)
        x = (coef @ self.basis.T.to(lat.dtype)).reshape(b, f, 3, h, w, BLOCK_T, BLOCK_S, BLOCK_S)
        return x.permute(0, 2, 1, 5, 3, 6, 4, 7).reshape(b, 3, f * BLOCK_T, h * BLOCK_S, w * BLOCK_S)

    def _norm_shape(self, t: torch.Tensor) -> torch.Tensor:
        return t.view(1, 1, -1, 1, 1)

    @torch.no_grad()
    def encode(self, video: torch.Tensor) -> torch.Tensor:
        """(B, 3, N, H, W) in [-1, 1] -> normalised latent (B, F, sum(coeffs), H/8, W/8)."""
        return (self.encode_raw(video) - self._norm_shape(self.shift)) / self._norm_shape(self.scale)

    @torch.no_grad()
    def decode(self, lat: torch.Tensor) -> torch.Tensor:
        """Normalised latent (B, F, C, h, w) -> (B, 3, N, H, W) (not clipped)."""
        return self.decode_raw(lat * self._norm_shape(self.scale) + self._norm_shape(self.shift))

    @torch.no_grad()
    def fit_normalisation(self, videos) -> None:
        """Set per-channel shift (mean) and scale (std, floored at 1e-3) from an iterable of videos;
        with ``normalisation="global"`` every channel's scale is the root mean of the channel variances."""
        s1 = torch.zeros(self.latent_channels, dtype=torch.float64)
        s2 = torch.zeros_like(s1)
        count = 0
        for v in videos:
            lat = self.encode_raw(v).double()
            s1 += lat.sum(dim=(0, 1, 3, 4))
            s2 += (lat**2).sum(dim=(0, 1, 3, 4))
            count += lat.numel() // lat.shape[2]
        if count == 0:
            raise ValueError("fit_normalisation: no videos")
        mean = s1 / count
        var = (s2 / count - mean**2).clamp_min(0)
        if self.normalisation == "global":
            var = var.mean().expand_as(var)
        std = var.sqrt().clamp_min(1e-3)
        self.shift.copy_(mean.float())
        self.scale.copy_(std.float())


class CogVideoXVAE(nn.Module):
    """Frozen CogVideoX VAE from a local diffusers folder (``{model_path}/vae``), same interface."""

    scale_spatial = 8
    scale_temporal = 4

    def __init__(self, model_path: str, dtype=torch.bfloat16, slicing: bool = True, tiling: bool = True):
        super().__init__()
        from diffusers import AutoencoderKLCogVideoX

        self.vae = AutoencoderKLCogVideoX.from_pretrained(model_path, subfolder="vae", torch_dtype=dtype)
        self.vae.requires_grad_(False).eval()
        if slicing:
            self.vae.enable_slicing()
        if tiling:
            self.vae.enable_tiling()
        self.scaling = float(self.vae.config.scaling_factor)

    @property
    def latent_channels(self) -> int:
        return int(self.vae.config.latent_channels)

    @torch.no_grad()
    def encode(self, video: torch.Tensor) -> torch.Tensor:
        check_frames(video.shape[2])
        lat = self.vae.encode(video.to(self.vae.device, self.vae.dtype)).latent_dist.mode()
        return (lat * self.scaling).permute(0, 2, 1, 3, 4).contiguous()

    @torch.no_grad()
    def decode(self, lat: torch.Tensor) -> torch.Tensor:
        lat = lat.permute(0, 2, 1, 3, 4).to(self.vae.device, self.vae.dtype) / self.scaling
        return self.vae.decode(lat).sample.float()


def round_trip_psnr_db(ae, video: torch.Tensor, pad_mode: str = "repeat_last") -> float:
    """PSNR (dB, display values in [0, 1]) of ``decode(encode(video))`` against ``video``, a (3, N, H, W) clip in
    [-1, 1]; N is padded to 4k + 1 frames with ``pad_mode`` (``infer.pad_frames``) and the padding dropped."""
    from lightcrafter.metrics import video_psnr_db

    from .data import to_display_frames
    from .frames import pad_to_4k1

    first = next(itertools.chain(ae.parameters(), ae.buffers()), None)
    device = first.device if first is not None else torch.device("cpu")
    padded, n = pad_to_4k1(video[None], pad_mode)
    with torch.no_grad():
        rt = ae.decode(ae.encode(padded.to(device)))[0, :, :n].clamp(-1, 1).cpu()
    return video_psnr_db(to_display_frames(rt), to_display_frames(video))


def check_round_trip(ae, dataset, floor_db: float | None, source: str, pad_mode: str = "repeat_last",
                     clips: int = 2) -> float | None:
    """Mean :func:`round_trip_psnr_db` of the targets of the first ``clips`` items of ``dataset``; a
    :class:`~lightcrafter.errors.DataError` naming ``source`` (where the autoencoder comes from) when it is below
    ``floor_db`` (``refiner.model.min_ae_round_trip_db``): the refiner's output is decoded by this autoencoder, so
    it can be no closer to a target than that. None (and no check) when ``floor_db`` is None or there is no item."""
    from lightcrafter.errors import DataError

    n = min(clips, len(dataset))
    if floor_db is None or n == 0:
        return None
    items = [dataset[i] for i in range(n)]
    db = sum(round_trip_psnr_db(ae, it["target"], pad_mode) for it in items) / n
    if not db >= floor_db:  # NaN fails too
        names = ", ".join(str(it.get("pair_id", i)) for i, it in enumerate(items))
        raise DataError(
            f"{source}: the autoencoder's round trip is {db:.1f} dB on the training targets ({names}), below "
            f"refiner.model.min_ae_round_trip_db = {floor_db:g}: refined clips could be no closer to their targets; "
            "use the model's own VAE weights (or more refiner.model.ae_coeffs for the tiny one), or lower the floor")
    return db
