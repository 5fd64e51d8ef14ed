"""Tiny latent space: CogVideoX shape semantics, causal first frame, round-trip quality."""

import numpy as np
import pytest
import torch

from lightcrafter.metrics import video_psnr_db
from lightcrafter.refiner import DCTPatchAutoencoder, FrameCountError, latent_frames, pad_to_4k1
from lightcrafter.refiner.toy import toy_pair

torch.set_num_threads(1)


def _disp(v):
    return ((v[0] + 1) / 2).clamp(0, 1).permute(1, 2, 3, 0).numpy()


@pytest.mark.parametrize("n", [1, 5, 9, 13])
def test_shapes(n):
    ae = DCTPatchAutoencoder([32, 8, 4])
    v = torch.rand(2, 3, n, 32, 48) * 2 - 1
    lat = ae.encode(v)
    assert lat.shape == (2, (n - 1) // 4 + 1, 44, 4, 6)
    assert ae.decode(lat).shape == v.shape
    assert latent_frames(n) == lat.shape[1]


def test_lossless_with_all_coefficients():
    ae = DCTPatchAutoencoder(256)
    v = torch.rand(1, 3, 9, 16, 32) * 2 - 1
    assert torch.allclose(ae.decode(ae.encode(v)), v, atol=1e-5)


def test_normalisation_round_trips():
    ae = DCTPatchAutoencoder([16, 4, 4])
    vids = [toy_pair(i)["target"][None] for i in range(2)]
    ae.fit_normalisation(vids)
    lat = torch.cat([ae.encode(v) for v in vids], dim=1)
    assert abs(float(lat.mean())) < 0.05 and abs(float(lat.std()) - 1) < 0.1
    assert torch.allclose(ae.decode(ae.encode(vids[0])), DCTPatchAutoencoder([16, 4, 4]).decode(
        DCTPatchAutoencoder([16, 4, 4]).encode(vids[0])), atol=1e-5)


def test_first_frame_is_causal():
    ae = DCTPatchAutoencoder(64)
    v = torch.rand(1, 3, 9, 16, 16) * 2 - 1
    w = v.clone()
    w[:, :, 1:] = torch.rand_like(w[:, :, 1:])
    a, b = ae.encode(v), ae.encode(w)
    assert torch.equal(a[:, 0], b[:, 0])
    assert not torch.allclose(a[:, 1], b[:, 1])


def test_round_trip_psnr_on_held_out_clips():
    ae = DCTPatchAutoencoder([40, 12, 12])  # the tiny default
    ae.fit_normalisation(toy_pair(i)["target"][None] for i in range(4))  # fit on "train" clips
    psnrs = []
    for seed in range(1000, 1004):  # held-out clips
        v = toy_pair(seed)["target"][None]
        psnrs.append(video_psnr_db(_disp(ae.decode(ae.encode(v))), _disp(v)))
    assert np.mean(psnrs) >= 35.0


def test_not_4k_plus_1_raises_or_pads():
    ae = DCTPatchAutoencoder(16)
    v = torch.rand(1, 3, 8, 16, 16)
    with pytest.raises(FrameCountError, match="4k\\+1"):
        ae.encode(v)
    with pytest.raises(FrameCountError):
        pad_to_4k1(v, "error")
    padded, n = pad_to_4k1(v, "repeat_last")
    assert n == 8 and padded.shape[2] == 9
    assert torch.equal(padded[:, :, 8], v[:, :, 7])


def test_bad_resolution_raises():
    with pytest.raises(ValueError, match="multiples of 16"):
        DCTPatchAutoencoder(16).encode(torch.rand(1, 3, 5, 24, 32))
