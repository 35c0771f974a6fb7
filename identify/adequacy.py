"""Model adequacy after the fit: is what is left over noise, as the noise model says?

Three tests; any failure flags the identification as a MISFIT (``AdequacyReport.misfit``), which
``hil identify`` turns into exit 13 (unless ``--accept-misfit``) and ``hil certify`` into an
ERROR certificate: a model that does not describe the data cannot feed a GO. Each test has a
false-alarm probability ``alpha`` (default 1e-3; Bonferroni-split over the outputs/pairs tested).

1. **Reduced chi^2 against a model-free noise estimate** (output-error ML path). The local
   polynomial method (LPM; Pintelon, Schoukens et al., *Mech. Syst. Signal Process.* 24 (2010)
   573-595) fits, in disjoint windows of ``2n+1`` neighbouring DFT bins, ``Y = G_loc U + T_loc`` with
   ``G_loc``, ``T_loc`` polynomials of degree ``R`` in the bin offset (transient included): its
   residual is noise only (``q = 2n+1 - rank`` complex dof per window) whatever the parametric model.
   ``reduced_chi2 = mean parametric residual power / LPM noise power`` over the same bins. Under a
   correct model the parametric fit is (locally) nested in the LPM one, so ``D = RSS_par - RSS_lpm``
   and ``RSS_lpm`` are independent projections of the noise: ``(D/d1)/(RSS_lpm/d2) ~ F(d1, d2)`` with
   ``d1 = 2 sum (2n+1-q)``, ``d2 = 2 sum q`` (real dof), i.e.
   ``reduced_chi2 = (sum q / sum(2n+1)) (1 + d1/d2 F)``; its expected range is the ``[alpha/2,
   1-alpha/2]`` quantile range of that law; above it: misfit (below: the noise is overestimated,
   reported, not flagged). (The ``p`` global parameters are ignored: they lower ``RSS_par`` by a
   fraction ``p / (2 m)``, which only makes the test conservative.)
   On the periodic H1 path the FRF's own variance is model-free already: ``reduced_chi2 =
   mean(|H_meas - H|^2 / (2 s^2))``, each term ``F(2, nu)``-distributed with the variance's ``nu``
   dof; range from the normal approximation of the mean of those terms (mean ``nu/(nu-2)``).
2. **Residual whiteness** (Ljung-Box on the normalized residual sequence). White time-domain noise
   gives DFT residuals ``E_k / sqrt(N sigma^2)`` that are independent, identically distributed
   circular complex Gaussians over the bins; the time-domain residual of a band is their inverse
   DFT shifted to base band, whose autocorrelation at lag ``tau`` is the ``tau``-th Fourier
   coefficient of the residual periodogram across the band. ``Q = 2 m sum_{tau=1..h} |rho_tau|^2``
   (``rho`` the circular autocorrelation of the complex sequence, ``m`` bins) is ~chi^2(2h) under
   whiteness; a misfit concentrated near a resonance, or coloured noise, makes the residual spectrum
   non-flat and ``Q`` large. (Over the full band ``0 < f < fs/2`` this IS Ljung-Box on the
   time-domain residual.) The same statistic is applied to the normalized FRF residuals of the
   periodic path.
3. **Input-residual cross-correlation** (output-error path). ``r(tau) = sum_k E~_k conj(U_k)
   e^{j 2 pi k tau / m}`` for ``|tau| <= L``: under a correct model the residual is independent of
   the (known) input, ``cov(r) = R_U`` (the circular autocorrelation of ``U`` across the band), and
   ``S = r^H R_U^-1 r`` is ~chi^2(2(2L+1)) (complex Gaussian). An unmodelled dynamics leaves a residual
   that is a filtered copy of the input: ``S`` large.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special  # the distributions' functions without scipy.stats (~0.5-1 s CPU to import)

logger = logging.getLogger(__name__)

__all__ = [
    "AdequacyReport",
    "AdequacyTest",
    "check_frf_fit",
    "check_ml_fit",
    "cross_correlation_test",
    "lpm_noise",
    "whiteness_test",
]


@dataclass
class AdequacyTest:
    """One test: ``statistic``, its null distribution's ``expected`` range (or ``p_value``), the
    level ``alpha`` it is judged at, and ``passed``."""

    name: str
    channel: str
    statistic: float
    passed: bool
    p_value: float | None = None
    expected: tuple[float, float] | None = None
    alpha: float = 1e-3
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "channel": self.channel,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "expected": list(self.expected) if self.expected else None,
            "alpha": self.alpha,
            "passed": self.passed,
            "details": self.details,
        }


@dataclass
class AdequacyReport:
    """All adequacy tests of one fit. ``misfit`` when any failed; ``reasons`` name them."""

    tests: list[AdequacyTest] = field(default_factory=list)

    @property
    def misfit(self) -> bool:
        return any(not t.passed for t in self.tests)

    @property
    def reasons(self) -> list[str]:
        out = []
        for t in self.tests:
            if not t.passed:
                rng = f" (expected {t.expected[0]:.3g}..{t.expected[1]:.3g})" if t.expected else ""
                pv = f", p = {t.p_value:.2g}" if t.p_value is not None else ""
                out.append(f"{t.name} of {t.channel}: {t.statistic:.4g}{rng}{pv}")
        return out

    def reduced_chi2(self) -> dict[str, float]:
        return {t.channel: t.statistic for t in self.tests if t.name == "reduced_chi2"}

    def to_dict(self) -> dict[str, Any]:
        return {"misfit": self.misfit, "reasons": self.reasons, "tests": [t.to_dict() for t in self.tests]}


# ----------------------------------------------------------------------------------------------- LPM
def lpm_noise(
    U: ArrayLike, Y: ArrayLike, *, order: int = 2, half_width: int | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Local polynomial method on consecutive DFT bins ``U`` (m, n_in), ``Y`` (m, n_out).

    Disjoint windows of ``2 half_width + 1`` bins (default: ``(n_in + 1)(order + 1) + 8`` bins, rounded
    up to odd, i.e. 8+ residual dof); in each, per output, least squares of ``Y`` on
    ``[U_i r^s, r^s]`` (``r`` the bin offset from the centre, ``s = 0..order``). Inputs without power
    in the record are dropped. Returns per window and output the residual sum of squares
    ``rss`` (n_win, n_out), the complex residual dof ``q`` (n_win,), the window starts and sizes."""
    Ua = np.asarray(U, complex)
    Ya = np.asarray(Y, complex)
    Ua = Ua[:, None] if Ua.ndim == 1 else Ua
    Ya = Ya[:, None] if Ya.ndim == 1 else Ya
    pw = np.sum(np.abs(Ua) ** 2, axis=0)
    Ua = Ua[:, pw > 1e-20 * max(float(np.max(pw)), 1e-300)]
    ni = Ua.shape[1]
    n_par = (ni + 1) * (order + 1)
    width = n_par + 8 if half_width is None else 2 * int(half_width) + 1
    width += 1 - width % 2
    m = Ya.shape[0]
    n_win = m // width
    starts = np.arange(n_win) * width
    rss = np.zeros((n_win, Ya.shape[1]))
    q = np.zeros(n_win)
    r = np.arange(width) - width // 2
    powers = (r[:, None] / max(width // 2, 1)) ** np.arange(order + 1)[None, :]  # (width, R+1), scaled
    for w, s0 in enumerate(starts):
        sl = slice(s0, s0 + width)
        cols = [Ua[sl, i : i + 1] * powers for i in range(ni)] + [powers.astype(complex)]
        X = np.concatenate(cols, axis=1)
        sol, _, rank, _ = np.linalg.lstsq(X, Ya[sl], rcond=1e-10)
        rss[w] = np.sum(np.abs(Ya[sl] - X @ sol) ** 2, axis=0)
        q[w] = width - rank
    return rss, q, starts, np.full(n_win, width)


# ------------------------------------------------------------------------------------ sequence tests
def whiteness_test(x: ArrayLike, *, lags: int = 20, alpha: float = 1e-3, channel: str = "") -> AdequacyTest:
    """Ljung-Box-type whiteness of a complex sequence ``x`` (module docstring, test 2). A REAL sequence
    (time-domain residuals, :mod:`hil.identify.held_ml`) has real autocorrelations, each carrying one
    degree of freedom: ``Q = m sum rho^2 ~ chi^2(h)`` instead of ``2 m sum |rho|^2 ~ chi^2(2 h)``."""
    real = bool(np.isrealobj(x))
    xx = np.asarray(x, complex)
    xx = xx[np.isfinite(xx)]
    m = xx.size
    h = int(min(lags, max(m // 5, 1)))
    X = np.fft.fft(xx)
    acf = np.fft.ifft(np.abs(X) ** 2)  # circular autocorrelation (sum_t x_{t+tau} conj(x_t))
    rho = acf[1 : h + 1] / acf[0].real
    k = 1 if real else 2
    Q = float(k * m * np.sum(np.abs(rho) ** 2))
    p = float(special.chdtrc(k * h, Q))
    return AdequacyTest("whiteness", channel, Q, p >= alpha, p, None, alpha, {"lags": h, "dof": k * h, "n": m})


def cross_correlation_test(
    e: ArrayLike, u: ArrayLike, *, lags: int = 10, alpha: float = 1e-3, channel: str = ""
) -> AdequacyTest:
    """Input-residual cross-correlation across the band (module docstring, test 3). ``e``: normalized
    residuals (unit variance per complex entry), ``u``: the input DFT on the same bins. Both REAL (time-
    domain residuals and input samples): ``S ~ chi^2(2L + 1)`` (a real Gaussian vector) instead of
    ``2 S ~ chi^2(2 (2L + 1))``."""
    real = bool(np.isrealobj(e) and np.isrealobj(u))
    ee = np.asarray(e, complex)
    uu = np.asarray(u, complex)
    m = ee.size
    L = int(min(lags, max(m // 10, 1)))
    taus = np.arange(-L, L + 1)
    cc = np.fft.ifft(np.fft.fft(ee) * np.conj(np.fft.fft(uu)))  # sum_k e_{k+tau} conj(u_k)
    r = cc[taus % m]
    au = np.fft.ifft(np.abs(np.fft.fft(uu)) ** 2)  # sum_k u_{k+tau} conj(u_k)
    R = au[(taus[:, None] - taus[None, :]) % m]  # cov(r_a, r_b) = sum_k u_{k-a} conj(u_{k-b})
    R = 0.5 * (R + R.conj().T)
    try:
        S = float(np.real(np.conj(r) @ np.linalg.solve(R, r)))
    except np.linalg.LinAlgError:
        S = float(np.real(np.conj(r) @ np.linalg.pinv(R) @ r))
    k = 1 if real else 2
    dof = k * taus.size
    p = float(special.chdtrc(dof, k * S))  # complex Gaussian: 2 S ~ chi^2(2 (2L+1)); real: S ~ chi^2(2L+1)
    return AdequacyTest("input_residual_correlation", channel, k * S, p >= alpha, p, None, alpha,
                        {"lags": L, "dof": dof, "n": m})


# ------------------------------------------------------------------------------------------- ML path
def check_ml_fit(
    model: Any, recs: Sequence[Any], theta: ArrayLike, sigma: ArrayLike, *, alpha: float = 1e-3, order: int = 2
) -> AdequacyReport:
    """Adequacy of an output-error ML fit (:mod:`hil.identify.timedomain`) on its DFT records."""
    from hil.identify.timedomain import _Problem

    prob = _Problem(model, recs)
    th = np.asarray(theta, float)
    sig = np.asarray(sigma, float)
    E, _ = prob.residuals(th[None], sig)
    outs = model.output_names
    ins = model.input_names
    no = len(outs)
    n_tests = 3 * no
    a = alpha / n_tests  # Bonferroni over outputs and tests (and inputs within the cross test)
    rep = AdequacyReport()
    # 1. reduced chi^2 vs the LPM noise (records pooled)
    rss_par = np.zeros(no)
    rss_lpm = np.zeros(no)
    n_bins = 0.0
    n_q = 0.0
    for e, r in zip(E, recs, strict=True):
        rss, q, starts, widths = lpm_noise(r.U, r.Y, order=order)
        for s0, wd in zip(starts, widths, strict=True):
            rss_par += np.sum(np.abs(e[0, s0 : s0 + wd]) ** 2, axis=0)
        rss_lpm += rss.sum(axis=0)
        n_bins += float(widths.sum())
        n_q += float(q.sum())
    for o, name in enumerate(outs):
        if n_q <= 0 or rss_lpm[o] <= 0:
            continue
        red = (rss_par[o] / n_bins) / (rss_lpm[o] / n_q)
        d1, d2 = 2 * (n_bins - n_q), 2 * n_q
        lo_f, hi_f = special.fdtri(d1, d2, np.array([a / 2, 1 - a / 2]))
        lo, hi = (n_q / n_bins) * (1 + d1 / d2 * lo_f), (n_q / n_bins) * (1 + d1 / d2 * hi_f)
        Fstat = (red * n_bins / n_q - 1) * d2 / d1
        p = float(special.fdtrc(d1, d2, Fstat))
        rep.tests.append(AdequacyTest("reduced_chi2", name, float(red), bool(red <= hi), p, (float(lo), float(hi)), a,
                                      {"lpm_dof": d2, "lpm_order": order}))
    # 2./3. whiteness and input-residual cross-correlation, per record pooled as sum of statistics
    for o, name in enumerate(outs):
        Qs, dof_w, Ss, dof_c = 0.0, 0, 0.0, 0
        for e, r in zip(E, recs, strict=True):
            en = e[0, :, o] / np.sqrt(r.n * sig[o] ** 2)
            w = whiteness_test(en, alpha=a)
            Qs += w.statistic
            dof_w += w.details["dof"]
            for i in range(len(ins)):
                if np.sum(np.abs(r.U[:, i]) ** 2) > 0:
                    c = cross_correlation_test(en, r.U[:, i], alpha=a)
                    Ss += c.statistic
                    dof_c += c.details["dof"]
        pw = float(special.chdtrc(dof_w, Qs))
        rep.tests.append(AdequacyTest("whiteness", name, Qs, pw >= a, pw, None, a, {"dof": dof_w}))
        if dof_c:
            pc = float(special.chdtrc(dof_c, Ss))
            rep.tests.append(AdequacyTest("input_residual_correlation", name, Ss, pc >= a, pc, None, a,
                                          {"dof": dof_c}))
    for t in rep.tests:
        logger.debug("adequacy %s %s: %.4g (p %s)", t.name, t.channel, t.statistic, t.p_value)
    if rep.misfit:
        logger.warning("model %s does not fit the data: %s", model.name, "; ".join(rep.reasons))
    return rep


# ------------------------------------------------------------------------------------------ FRF path
def check_frf_fit(model: Any, est: Any, theta: ArrayLike, *, alpha: float = 1e-3) -> AdequacyReport:
    """Adequacy of an H1-FRF fit (periodic path): reduced chi^2 against the FRF's own variance and
    the whiteness of the normalized FRF residuals across frequency, per output (module docstring)."""
    H = model.frf(np.asarray(theta, float), est.w)
    R = H - est.H
    s = est.sigma
    nu = est.nu
    ok = np.isfinite(R) & np.isfinite(s) & (s > 0)
    rep = AdequacyReport()
    no = len(model.output_names)
    a = alpha / (2 * no)
    for o, name in enumerate(model.output_names):
        m = ok[:, o, :]
        if not np.any(m):
            continue
        t = (np.abs(R[:, o, :]) ** 2 / (2 * s[:, o, :] ** 2))[m]  # each ~ F(2, nu)
        v = np.broadcast_to(nu[:, o, :], m.shape)[m].astype(float)
        v = np.maximum(v, 4.5)
        mean_t = v / (v - 2)
        var_t = v**2 * v / ((v - 2) ** 2 * (v - 4))  # var F(2, nu) = nu^2 nu / ((nu-2)^2 (nu-4))
        n = t.size
        red = float(np.mean(t))
        mu = float(np.mean(mean_t))
        sd = float(np.sqrt(np.sum(var_t)) / n)
        zq = float(special.ndtri(1 - a / 2))
        lo, hi = mu - zq * sd, mu + zq * sd
        p = float(special.ndtr(-(red - mu) / sd)) if sd > 0 else 1.0
        rep.tests.append(AdequacyTest("reduced_chi2", name, red, red <= hi, p, (lo, hi), a, {"n": n}))
        x = R[:, o, :][m] / (np.sqrt(2) * s[:, o, :][m])
        rep.tests.append(whiteness_test(x, alpha=a, channel=name))
    if rep.misfit:
        logger.warning("model %s does not fit the FRF: %s", model.name, "; ".join(rep.reasons))
    return rep
