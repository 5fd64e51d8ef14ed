"""Classifier-free guidance acts on the proxy latent only (prompt embedding identical)."""

import pytest
import torch

from lightcrafter.refiner import Refiner, resolve_config
from lightcrafter.refiner.conditioning import drop_proxy_latent, noisy_proxy, sample_log_sigma
from lightcrafter.refiner.sampler import guided_prediction

torch.set_num_threads(1)


class Recorder(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.proxies = []

    def forward(self, z, zp, t):
        self.proxies.append(zp.clone())
        return z * 0 + zp.mean()


def test_uncond_branch_gets_zeroed_proxy():
    m = Recorder()
    z, zp = torch.randn(1, 3, 4, 2, 2), torch.randn(1, 3, 4, 2, 2) + 1
    out = guided_prediction(m, z, zp, 500, 6.0)
    assert len(m.proxies) == 2
    assert torch.equal(m.proxies[0], zp) and torch.equal(m.proxies[1], torch.zeros_like(zp))
    assert torch.allclose(out, torch.full_like(z, 6.0 * float(zp.mean())))
    m.proxies.clear()
    guided_prediction(m, z, zp, 500, 1.0)
    assert len(m.proxies) == 1  # scale 1: no unconditional pass


class AnchoredRecorder(Recorder):
    proxy_anchor = "x0"

    def forward(self, z, zp, t, anchor=None):
        self.proxies.append((zp.clone(), None if anchor is None else anchor.clone()))
        return z * 0 + zp.mean()


def test_anchored_uncond_branch_keeps_the_anchor_on_the_proxy():
    m = AnchoredRecorder()
    z, zp = torch.randn(1, 3, 4, 2, 2), torch.randn(1, 3, 4, 2, 2) + 1
    guided_prediction(m, z, zp, 500, 4.0)
    (c_in, c_anchor), (u_in, u_anchor) = m.proxies
    assert torch.equal(c_in, zp) and c_anchor is None  # conditional: anchor defaults to the proxy input
    assert torch.equal(u_in, torch.zeros_like(zp)) and torch.equal(u_anchor, zp)


@pytest.mark.parametrize("anchor", ["none", "x0"])
def test_guidance_is_noop_when_proxy_is_the_dropout_value(anchor):
    torch.manual_seed(0)
    model = Refiner(resolve_config({"model": {"ae_coeffs": [8, 4, 4], "proxy_anchor": anchor}})).eval()
    if anchor != "none":  # leave the zero initialisation so the test is not trivially true
        torch.nn.init.normal_(model.transformer.proj_out.weight, std=0.02)
    z = torch.randn(1, 3, model.latent_channels, 4, 6)
    zero = torch.zeros_like(z)
    with torch.no_grad():
        cond = model(z, zero, torch.tensor([300]))
        guided = guided_prediction(model, z, zero, 300, 6.0)
    assert torch.allclose(guided, cond, atol=1e-5)  # only the proxy differs between the branches


def test_dropout_rate_and_noise_scale():
    g = torch.Generator().manual_seed(0)
    zp = torch.ones(1, 2, 3, 2, 2)
    drops = sum(drop_proxy_latent(zp, 0.25, g)[1] for _ in range(4000))
    assert 0.2 < drops / 4000 < 0.3
    sig = torch.tensor([sample_log_sigma(g) for _ in range(4000)])
    assert abs(float(sig.mean()) + 3.0) < 0.05 and abs(float(sig.std()) - 0.5) < 0.05
    p = torch.zeros(3, 5, 64, 64)
    n = noisy_proxy(p, -3.0, g)
    assert abs(float(n.std()) - float(torch.exp(torch.tensor(-3.0)))) < 2e-3
