"""Training-time conditioning: pixel-space noise on the proxy and proxy-latent dropout.

* Noise (paper appendix, "Robust Conditioning via Input Noise"): P~ = P + sigma * eta,
  eta ~ N(0, I), log sigma ~ N(-3, 0.5), one sigma per training step, on display values in [-1, 1],
  applied BEFORE encoding. Hence proxy latents cannot be cached (they change every step); target
  latents can (the encoder is deterministic).
* Dropout: with probability p the proxy latent is replaced by zeros -- the same value the
  unconditional CFG branch uses at inference, so guidance acts on the proxy alone.
"""

from __future__ import annotations

import torch


def sample_log_sigma(generator: torch.Generator, mean: float = -3.0, std: float = 0.5) -> float:
    return float(mean + std * torch.randn((), generator=generator))


def noisy_proxy(proxy: torch.Tensor, log_sigma: float, generator: torch.Generator) -> torch.Tensor:
    """proxy (.., in [-1, 1]) + exp(log_sigma) * N(0, I); not clipped."""
    eta = torch.randn(proxy.shape, generator=generator)
    return proxy + float(torch.exp(torch.tensor(log_sigma))) * eta


def drop_proxy_latent(zp: torch.Tensor, p: float, generator: torch.Generator) -> tuple[torch.Tensor, bool]:
    """Zero the proxy latent with probability p; returns (latent, dropped)."""
    dropped = bool(torch.rand((), generator=generator) < p)
    return (torch.zeros_like(zp) if dropped else zp), dropped
