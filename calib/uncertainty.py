"""The expanded uncertainty U95 (GUM, k for about 95 % coverage) of a point measured now, from
the evidence of a check standard: the norms of the prediction errors of measured points whose
true position is known (the in-line spheres measured with parameters not trained on them).

Each error is a 3-D vector; with the same standard deviation sigma per coordinate, its squared
norm is sigma^2 chi-square(3), so n norms carry 3n degrees of freedom about sigma^2. The upper
one-sided 95 % confidence bound of sigma^2 from them is sum(e^2) / chi2.ppf(0.05, 3n): few
observations state a larger uncertainty (one norm: 2.9x its own value as sigma, as against about
0.58x with many). The norm of a new point's error has its 95th percentile at
sigma sqrt(chi2.ppf(0.95, 3)) = 2.80 sigma, i.e. 1.62x its RMS (REFERENCE.md: an honest U95 sits
near 1.6x the true RMS). So U95 = 2.80 sigma_upper, plus, in quadrature per coordinate, the terms
that the evidence does not contain (`extra_sigma_mm`).

Pure numbers (scipy's chi-square quantiles, `chi2_ppf`); which residuals are evidence is the
caller's (app.line.accuracy).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: one-sided confidence of the evidence's upper bound, and the coverage of the statement
CONFIDENCE = 0.95
COVERAGE = 0.95


def chi2_ppf(p: float, dof: float) -> float:
    """The `p` quantile of chi-square with `dof` degrees of freedom: what scipy.stats.chi2.ppf
    computes (2 gammaincinv(dof / 2, p)), from scipy.special alone (scipy.stats takes about a
    second to import, in every process that states an uncertainty)."""
    from scipy.special import gammaincinv

    return 2.0 * float(gammaincinv(0.5 * dof, p))


def sigma_upper_mm(norms_mm: Sequence[float], confidence: float = CONFIDENCE) -> float:
    """The upper one-sided `confidence` bound of the per-coordinate standard deviation [mm] from
    the norms of n 3-D errors (module docstring); nan without any."""
    n = len(norms_mm)
    if n == 0:
        return math.nan
    ss = math.fsum(float(e) ** 2 for e in norms_mm)
    return math.sqrt(ss / chi2_ppf(1.0 - confidence, 3 * n))


def norm_quantile(coverage: float = COVERAGE) -> float:
    """The `coverage` quantile of the norm of a 3-D error, in per-coordinate sigmas (2.80 for
    95 %)."""
    return math.sqrt(chi2_ppf(coverage, 3))


def u95_mm(norms_mm: Sequence[float], extra_sigma_mm: float = 0.0) -> float:
    """U95 [mm] of the norm of a point's error (module docstring): nan without evidence."""
    s = sigma_upper_mm(norms_mm)
    if math.isnan(s):
        return math.nan
    return norm_quantile() * math.hypot(s, extra_sigma_mm)


#: VDA 5: the expanded uncertainty at most this share of a tolerance T (2 U / T)
VDA5_MAX_RATIO = 0.30
#: the tolerance T [mm] a limit stands for when the plant gives none (+-0.5 mm, a body's)
DEFAULT_TOLERANCE_MM = 1.0
#: a healthy cell's own U95 times this is where it can no longer vouch: its uncertainty grew
#: by half (its variance 2.25x) before a window is suspect, so that a cell stating its usual
#: figure is not at its limit
HEALTHY_MARGIN = 1.5


def accuracy_limit_mm(tolerance_mm: float, own_u95_mm: float | None) -> tuple[float, str]:
    """The U95 a cell is held to: VDA 5's 2U/T <= 30 % of the tolerance (0: +-0.5 mm), or, when
    the cell's own U95 (its commissioning's workspace validation) is so near that, HEALTHY_MARGIN
    times its own; with the reason in words."""
    t = tolerance_mm if tolerance_mm > 0 else DEFAULT_TOLERANCE_MM
    vda = VDA5_MAX_RATIO / 2.0 * t
    if own_u95_mm is None or not math.isfinite(own_u95_mm) or HEALTHY_MARGIN * own_u95_mm <= vda:
        return vda, f"VDA 5 (2 U95 / T <= 30 %) for a tolerance of {t:g} mm"
    own = HEALTHY_MARGIN * own_u95_mm
    return own, (
        f"{HEALTHY_MARGIN:g} x the cell's own U95 {own_u95_mm:.3f} mm (VDA 5's {vda:.3f} mm for a"
        f" tolerance of {t:g} mm would hold a healthy cell at its limit; 2 U95 / T"
        f" {200 * own_u95_mm / t:.0f} %)"
    )


def shown_larger(
    norms_mm: Sequence[float], sigma_mm: float, confidence: float = CONFIDENCE
) -> bool:
    """The norms of n 3-D errors show a per-coordinate standard deviation larger than
    `sigma_mm` at `confidence` (sum(e^2) / sigma^2 above chi2.ppf(confidence, 3n)): a stated
    sigma the evidence contradicts. None measured: not shown."""
    n = len(norms_mm)
    if n == 0:
        return False
    ss = math.fsum(float(e) ** 2 for e in norms_mm)
    return ss / sigma_mm**2 > chi2_ppf(confidence, 3 * n)


def shown_worse(
    candidate_mm: Sequence[float], current_mm: Sequence[float], confidence: float = CONFIDENCE
) -> bool:
    """The candidate's error norms on the same held-out points (paired with `current_mm`) are
    shown larger at `confidence`: a one-sided paired t test of the squared norms'
    differences. A few held-out points rarely show a difference of a few micrometres; deciding
    between two versions on their RMS alone decides on noise."""
    from scipy.stats import t as t_dist

    n = len(candidate_mm)
    if n != len(current_mm):
        raise ValueError("the candidate's and the current norms must be paired")
    if n < 2:
        return False
    d = [float(a) ** 2 - float(b) ** 2 for a, b in zip(candidate_mm, current_mm, strict=True)]
    mean = math.fsum(d) / n
    sd = math.sqrt(math.fsum((x - mean) ** 2 for x in d) / (n - 1))
    if sd == 0.0:
        return mean > 0.0
    return mean / (sd / math.sqrt(n)) > float(t_dist.ppf(confidence, n - 1))


def larger_rms_bound(n: int, n_reference: int, confidence: float = CONFIDENCE) -> float:
    """The ratio of the RMS of n 3-D error norms to that of n_reference others above which the
    first are shown to have the larger per-coordinate sigma at `confidence`: sqrt of the F
    distribution's quantile with 3 n and 3 n_reference degrees of freedom (each norm^2 carries
    3); inf without errors on either side."""
    from scipy.stats import f as f_dist

    if n == 0 or n_reference == 0:
        return math.inf
    return math.sqrt(float(f_dist.ppf(confidence, 3 * n, 3 * n_reference)))


def shown_larger_than(
    norms_mm: Sequence[float], reference_mm: Sequence[float], confidence: float = CONFIDENCE
) -> bool:
    """The norms of n 3-D errors show a larger per-coordinate sigma than those of another,
    independent set at `confidence` (a one-sided F test of their mean squares, unpaired: the
    workspace validation after a maintenance against the one before it, at other positions)."""
    if not norms_mm or not reference_mm:
        return False
    ms = math.fsum(float(e) ** 2 for e in norms_mm) / len(norms_mm)
    ms_ref = math.fsum(float(e) ** 2 for e in reference_mm) / len(reference_mm)
    if ms_ref == 0.0:
        return ms > 0.0
    return math.sqrt(ms / ms_ref) > larger_rms_bound(len(norms_mm), len(reference_mm), confidence)
