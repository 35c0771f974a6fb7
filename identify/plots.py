"""Figures of an identification (matplotlib imported lazily, Agg backend; ``corner``, declared in
the ``report`` extra, used when installed, else a plain pairwise scatter grid).

All functions return the :class:`matplotlib.figure.Figure` and save it when ``path`` is given.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from hil.identify.api import IdentificationResult

logger = logging.getLogger(__name__)

__all__ = ["plot_coherence", "plot_corner", "plot_frf", "plot_residuals"]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: str | None) -> Any:
    if path:
        fig.savefig(path, dpi=120, bbox_inches="tight")
        logger.info("figure saved to %s", path)
    return fig


def plot_frf(res: IdentificationResult, *, n_draws: int = 200, seed: int = 0, path: str | None = None) -> Any:
    """Measured FRF (magnitude and phase, +-2 sigma) with the posterior-median model and its 90 % band."""
    plt = _plt()
    est, mdl = res.frf, res.model
    no, ni = est.H.shape[1:]
    fig, axes = plt.subplots(2, no * ni, figsize=(4.5 * no * ni, 6), squeeze=False, sharex=True)
    rng = np.random.default_rng(seed)
    samp = res.posterior.samples[:, : mdl.n_params]
    draws = samp[rng.choice(samp.shape[0], size=min(n_draws, samp.shape[0]), replace=False)]
    Hd = mdl.frf(draws, est.w)  # (n, nf, no, ni)
    Hmed = mdl.frf(np.median(samp, axis=0), est.w)
    for o in range(no):
        for i in range(ni):
            c = o * ni + i
            ax_m, ax_p = axes[0, c], axes[1, c]
            H = est.H[:, o, i]
            s = est.sigma[:, o, i]
            ax_m.errorbar(est.f, np.abs(H), yerr=2 * s, fmt=".", ms=2, lw=0.5, label="H1 (+-2 sigma)")
            lo, hi = np.quantile(np.abs(Hd[:, :, o, i]), [0.05, 0.95], axis=0)
            ax_m.fill_between(est.f, lo, hi, alpha=0.4, color="C1", label="90 % band")
            ax_m.plot(est.f, np.abs(Hmed[:, o, i]), "C1", lw=1, label="posterior median")
            ax_m.set(xscale="log", yscale="log", title=f"{est.input_names[i]} -> {est.output_names[o]}")
            ax_p.plot(est.f, np.degrees(np.angle(H)), ".", ms=2)
            ax_p.plot(est.f, np.degrees(np.angle(Hmed[:, o, i])), "C1", lw=1)
            ax_p.set(xlabel="frequency [Hz]", ylabel="phase [deg]")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def plot_coherence(res: IdentificationResult, *, path: str | None = None) -> Any:
    """Multiple coherence of each output over the analysis band."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3))
    for o, name in enumerate(res.frf.output_names):
        ax.plot(res.frf.f, res.frf.coherence[:, o], label=name)
    ax.set(xscale="log", ylim=(0, 1.02), xlabel="frequency [Hz]", ylabel="coherence")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def plot_residuals(res: IdentificationResult, *, path: str | None = None) -> Any:
    """Normalized residuals (H_model - H1)/sigma, real and imaginary parts, at the posterior median."""
    plt = _plt()
    est, mdl = res.frf, res.model
    Hm = mdl.frf(np.median(res.posterior.samples[:, : mdl.n_params], axis=0), est.w)
    r = (Hm - est.H) / est.sigma
    fig, ax = plt.subplots(figsize=(6, 3))
    no, ni = est.H.shape[1:]
    for o in range(no):
        for i in range(ni):
            ax.plot(est.f, r[:, o, i].real, ".", ms=2, label=f"Re {est.output_names[o]}/{est.input_names[i]}")
            ax.plot(est.f, r[:, o, i].imag, "x", ms=2, label=f"Im {est.output_names[o]}/{est.input_names[i]}")
    ax.axhline(2, color="k", lw=0.5, ls="--")
    ax.axhline(-2, color="k", lw=0.5, ls="--")
    ax.set(xscale="log", xlabel="frequency [Hz]", ylabel="residual / sigma")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def plot_corner(res: IdentificationResult, *, truths: Any = None, path: str | None = None) -> Any:
    """Corner plot of the posterior (``corner`` from the ``report`` extra if installed, else a
    pairwise scatter grid)."""
    plt = _plt()
    samples = res.posterior.samples
    names = list(res.posterior.names)
    try:
        import corner  # type: ignore[import-not-found]
    except ImportError:
        logger.info("corner not installed (pip install 'hil-certify[report]'): plain pairwise scatter grid")
    else:
        fig = corner.corner(samples, labels=names, truths=truths, quantiles=[0.05, 0.5, 0.95])
        return _save(fig, path)
    d = samples.shape[1]
    fig, axes = plt.subplots(d, d, figsize=(1.8 * d, 1.8 * d), squeeze=False)
    sub = samples[:: max(1, samples.shape[0] // 3000)]
    for r in range(d):
        for c in range(d):
            ax = axes[r, c]
            if c > r:
                ax.axis("off")
                continue
            if r == c:
                ax.hist(sub[:, c], bins=40, histtype="step", color="k")
            else:
                ax.plot(sub[:, c], sub[:, r], ",", alpha=0.3, color="k")
            if truths is not None:
                ax.axvline(truths[c], color="C3", lw=0.8)
                if r != c:
                    ax.axhline(truths[r], color="C3", lw=0.8)
            ax.tick_params(labelsize=5)
            if r == d - 1:
                ax.set_xlabel(names[c], fontsize=7)
            if c == 0 and r > 0:
                ax.set_ylabel(names[r], fontsize=7)
    fig.tight_layout()
    return _save(fig, path)
