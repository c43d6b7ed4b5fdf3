"""Interval statistics of the result tables: Student-t confidence intervals, paired differences, and
the agreement of a difference's direction with the paper's.

A table cell aggregates the n values of one row (method) and one metric over the runs of a suite,
one run per (scene, trainer seed). The cell shows the mean and the half-width of the Student-t
confidence interval of the mean, t_{(1 + level) / 2, n - 1} * s / sqrt(n) with s the sample standard
deviation (n - 1 denominator); the runs are treated as independent samples (scene-to-scene variation
then dominates the width). n < 2 has no interval.

The paired difference of a row to the reference row pairs the runs by (scene, seed): d_k = row_k -
reference_k over the pairs both rows have, and the same t-interval of the mean of d
(scipy.stats.ttest_rel's interval). It is "significant" when its interval excludes 0, which is the
same as its two-sided p-value (`Interval.p`) being below 1 - level.

One finding of the paper is tested by several such differences (rows x metrics), and at 95 % about
one in twenty of them excludes 0 by chance alone when no effect exists. `holm` adjusts the p-values
of such a family (Holm's step-down method: the family-wise error rate is at most 1 - level whatever
the dependence between the tests), so a table can say which verdicts survive the multiplicity."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Hashable, Iterable, List, Mapping, Optional, Sequence, Tuple

LEVEL = 0.95


def t_quantile(p: float, df: int) -> float:
    """The p-quantile of Student's t distribution with df degrees of freedom (scipy.stats.t.ppf)."""
    from scipy.stats import t  # deferred: scipy.stats costs ~1 s to import

    return float(t.ppf(p, df))


def t_two_sided_p(stat: float, df: int) -> float:
    """P(|T| >= |stat|) for Student's t with df degrees of freedom (scipy.stats.t.sf)."""
    from scipy.stats import t

    return float(min(1.0, 2.0 * t.sf(abs(stat), df)))


@dataclass(frozen=True)
class Interval:
    """mean +- half (half None when n < 2: no interval); n = number of values; p = two-sided p-value
    of the t-test of mean 0 (None without an interval; a difference's interval excludes 0 exactly
    when p < 1 - level)."""

    mean: Optional[float]
    half: Optional[float]
    n: int
    p: Optional[float] = None

    @property
    def low(self) -> Optional[float]:
        return None if self.mean is None or self.half is None else self.mean - self.half

    @property
    def high(self) -> Optional[float]:
        return None if self.mean is None or self.half is None else self.mean + self.half

    @property
    def excludes_zero(self) -> Optional[bool]:
        """True / False, or None without an interval."""
        if self.half is None or self.mean is None:
            return None
        return self.low > 0 or self.high < 0


def mean_ci(values: Iterable[float], level: float = LEVEL) -> Interval:
    """Mean and Student-t confidence half-width of the mean of `values` (NaN / None dropped)."""
    xs = [
        float(v) for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))
    ]
    n = len(xs)
    if n == 0:
        return Interval(None, None, 0)
    m = sum(xs) / n
    if n < 2:
        return Interval(m, None, n)
    if any(math.isinf(x) for x in xs):
        return Interval(m, None, n)
    var = sum((x - m) ** 2 for x in xs) / (n - 1)
    se = math.sqrt(var / n)
    half = t_quantile(0.5 + level / 2, n - 1) * se
    p = (1.0 if m == 0 else 0.0) if se == 0 else t_two_sided_p(m / se, n - 1)
    return Interval(m, half, n, p)


def holm(pvalues: Sequence[Optional[float]]) -> List[Optional[float]]:
    """Holm's step-down adjusted p-values of one family of tests, in the input order (None, a test
    without a p-value, stays None and is not counted in the family). With the m p-values sorted
    ascending, p_(k) becomes max over j <= k of min(1, (m - j + 1) p_(j)); a test is significant at
    family-wise level alpha when its adjusted value is < alpha."""
    order = sorted((i for i, v in enumerate(pvalues) if v is not None), key=lambda i: pvalues[i])
    m = len(order)
    out: List[Optional[float]] = [None] * len(pvalues)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * float(pvalues[i])))
        out[i] = running
    return out


def paired_diff(
    values: Mapping[Hashable, float], reference: Mapping[Hashable, float], level: float = LEVEL
) -> Interval:
    """Interval of the mean of values[k] - reference[k] over the keys (e.g. (scene, seed)) both have
    a value for."""

    def ok(v):
        return v is not None and not (isinstance(v, float) and math.isnan(v))

    keys = [k for k in values if k in reference and ok(values[k]) and ok(reference[k])]
    return mean_ci([float(values[k]) - float(reference[k]) for k in keys], level)


def scene_paired_diff(
    values: Mapping[Hashable, float], reference: Mapping[Hashable, float], level: float = LEVEL
) -> Interval:
    """Interval of the mean over SCENES of values - reference: the paired differences over the
    (scene, seed) keys both have are averaged per scene (keys[0]), and the Student-t interval is
    taken over those scene means (n = scenes, n - 1 degrees of freedom). Where paired_diff treats
    every (scene, seed) run as an independent sample, and so answers for these scenes, this one
    answers for scenes like these: an effect that holds on one scene and reverses on another
    stays open here however many seeds each has."""

    def ok(v):
        return v is not None and not (isinstance(v, float) and math.isnan(v))

    diffs = {
        k: float(values[k]) - float(reference[k])
        for k in values
        if k in reference and ok(values[k]) and ok(reference[k])
    }
    return scene_mean_ci(diffs, level)


def scene_mean_ci(diffs: Mapping[Hashable, float], level: float = LEVEL) -> Interval:
    """Interval of the mean over scenes of {(scene, seed): difference}: each scene's (keys[0])
    differences averaged first, the Student-t interval over those scene means (scene_paired_diff's
    second half)."""
    per: Dict[Hashable, list] = {}
    for k, d in diffs.items():
        per.setdefault(k[0], []).append(float(d))
    return mean_ci([sum(d) / len(d) for d in per.values()], level)


@dataclass(frozen=True)
class Heterogeneity:
    """An F-test of a factor: F = (between-level mean square) / (within or residual mean square),
    p = P(F_{df_between, df_within} >= F). `scene_heterogeneity`: scenes across one difference's
    pairs (df_between = scenes - 1, df_within = runs - scenes); `rows_differ`: rows across the
    (scene, seed) pairs they share."""

    f: float
    df_between: int
    df_within: int
    p: float


def scene_heterogeneity(diffs: Mapping[Hashable, float]) -> Optional[Heterogeneity]:
    """Does an effect differ between scenes by more than its seeds scatter? {(scene, seed):
    difference} -> the one-way ANOVA of the differences with the scene (keys[0]) as the factor and
    the seeds as replicates (scipy.stats.f_oneway's F and p), or None without at least two scenes
    and one scene with two seeds (no within-scene spread to compare with). A small p says the
    per-scene pattern is more than seed noise; a large one, that the second seed did not repeat it
    beyond what one run's draw moves. A within-scene spread of 0 gives F = inf and p = 0 when
    the scene means differ (p = 1 when they do not)."""
    per: Dict[Hashable, List[float]] = {}
    for k, d in diffs.items():
        if d is not None and not (isinstance(d, float) and math.isnan(d)):
            per.setdefault(k[0], []).append(float(d))
    k = len(per)
    n = sum(len(v) for v in per.values())
    if k < 2 or n - k < 1:
        return None
    grand = sum(sum(v) for v in per.values()) / n
    ssb = sum(len(v) * (sum(v) / len(v) - grand) ** 2 for v in per.values())
    ssw = sum(sum((x - sum(v) / len(v)) ** 2 for x in v) for v in per.values())
    df1, df2 = k - 1, n - k
    if ssw == 0:
        return Heterogeneity(math.inf if ssb > 0 else 0.0, df1, df2, 0.0 if ssb > 0 else 1.0)
    from scipy.stats import f as f_dist

    f = (ssb / df1) / (ssw / df2)
    return Heterogeneity(f, df1, df2, float(f_dist.sf(f, df1, df2)))


def rows_differ(values: Mapping[Hashable, Mapping[Hashable, float]]) -> Optional[Heterogeneity]:
    """Do several rows differ from one another beyond the pairs' scatter? {row: {(scene, seed):
    value}} -> the two-way analysis of variance without replication over the (scene, seed) blocks
    that every row has (a finite value in each), rows as the factor: F = (between-row mean square)
    / (residual mean square), df_between = rows - 1, df_within = (blocks - 1)(rows - 1). Each
    block's level cancels, so the values may be the rows' differences to one reference (the same
    F as the rows' own values). For two rows it is the paired t-test (F = t^2, the same p). None
    with fewer than two rows or two common blocks. A residual of 0 gives F = inf and p = 0 when
    the row means differ (p = 1 when they do not), as `scene_heterogeneity`."""

    def finite(x) -> bool:
        return x is not None and math.isfinite(float(x))

    names = list(values)
    if len(names) < 2:
        return None
    blocks = [b for b in values[names[0]] if all(finite(values[n].get(b)) for n in names)]
    k, nb = len(names), len(blocks)
    if nb < 2:
        return None
    y = [[float(values[n][b]) for n in names] for b in blocks]  # blocks x rows
    grand = sum(map(sum, y)) / (k * nb)
    row_mean = [sum(y[i][j] for i in range(nb)) / nb for j in range(k)]
    block_mean = [sum(r) / k for r in y]
    ss_rows = nb * sum((m - grand) ** 2 for m in row_mean)
    ss_res = sum(
        (y[i][j] - row_mean[j] - block_mean[i] + grand) ** 2 for i in range(nb) for j in range(k)
    )
    df1, df2 = k - 1, (nb - 1) * (k - 1)
    if ss_res <= 1e-12 * max(1.0, ss_rows):
        return Heterogeneity(
            math.inf if ss_rows > 0 else 0.0, df1, df2, 0.0 if ss_rows > 0 else 1.0
        )
    from scipy.stats import f as f_dist

    f = (ss_rows / df1) / (ss_res / df2)
    return Heterogeneity(f, df1, df2, float(f_dist.sf(f, df1, df2)))


@dataclass(frozen=True)
class SeedNoise:
    """How much one run moves with its trainer seed alone: over the groups (e.g. (scene, row)) that
    have runs with two or more seeds, `rms_diff` is the root mean square difference between two
    runs of one group, sqrt(2) * the pooled within-group standard deviation (for two seeds per
    group: sqrt(mean of (seed 1 - seed 0)^2)); `largest` the largest spread within one group
    (max - min); `groups` how many groups stand behind it."""

    rms_diff: float
    largest: float
    groups: int


def seed_noise(values: Mapping[Hashable, Sequence[float]]) -> Optional[SeedNoise]:
    """{group: [one value per trainer seed]} -> SeedNoise over the groups with two or more values
    (None where no group has two). The pooled within-group variance is sum over groups of the
    squared deviations from the group mean, over sum of (values - 1); a difference of two runs
    of a group has twice that variance when the seed adds independent noise of the same size
    everywhere."""
    ss, df, largest, groups = 0.0, 0, 0.0, 0
    for v in values.values():
        xs = [float(x) for x in v if x is not None and not (isinstance(x, float) and math.isnan(x))]
        if len(xs) < 2:
            continue
        m = sum(xs) / len(xs)
        ss += sum((x - m) ** 2 for x in xs)
        df += len(xs) - 1
        largest = max(largest, max(xs) - min(xs))
        groups += 1
    if not groups:
        return None
    return SeedNoise(math.sqrt(2.0 * ss / df), largest, groups)


# --------------------------------------------------------------------------------------------------
# agreement with the paper
# --------------------------------------------------------------------------------------------------
AGREE, DISAGREE, NOT_SIGNIFICANT, PAPER_TIE, NA = (
    "agree",
    "disagree",
    "not significant",
    "paper tie",
    "n/a",
)


def sign_text(x: Optional[float]) -> str:
    """ "+", "-" or "0" (n/a for None)."""
    if x is None:
        return NA
    return "+" if x > 0 else "-" if x < 0 else "0"


def agreement(
    paper_diff: Optional[float], ours: Optional[Interval], tol: float = 1e-9
) -> Tuple[str, str, str]:
    """(paper's direction, our direction, verdict) of a difference row - reference.

    paper_diff: the paper's row value minus its reference value (None when the paper lacks one of
    them); ours: our paired-difference interval. Our direction is "n.s." when our interval includes
    0 (or "n/a" without one). Verdict: "agree" (same sign, ours significant), "disagree" (opposite
    signs, ours significant), "not significant" (our interval includes 0), "paper tie" (the paper's
    two values are equal as printed, ours significant), "n/a"."""
    p = None if paper_diff is None else (0.0 if abs(paper_diff) <= tol else paper_diff)
    if ours is None or ours.mean is None or ours.half is None:
        return sign_text(p), NA, NA
    if not ours.excludes_zero:
        return sign_text(p), "n.s.", NA if p is None else NOT_SIGNIFICANT
    o = sign_text(ours.mean)
    if p is None:
        return NA, o, NA
    if p == 0:
        return "0", o, PAPER_TIE
    return sign_text(p), o, AGREE if (p > 0) == (ours.mean > 0) else DISAGREE


def by_key(rows: Iterable[dict], key: str) -> Dict[Tuple, float]:
    """{(scene, seed): value} of one metric over table rows (seed defaults to 0; duplicates
    averaged)."""
    acc: Dict[Tuple, list] = {}
    for r in rows:
        v = r.get(key)
        if v is None or (isinstance(v, float) and math.isnan(v)):
            continue
        acc.setdefault((r.get("scene"), r.get("seed", 0) or 0), []).append(float(v))
    return {k: sum(v) / len(v) for k, v in acc.items()}


# --------------------------------------------------------------------------------------------------
# text of an interval and of a heterogeneity test (one formatter each for every table that prints
# them: `pairs`, `repeats`, `region-pairs` and the results page's controls and findings)
# --------------------------------------------------------------------------------------------------
def interval_text(iv, fmt: str, n_label: str = "") -> str:
    """mean ± half († where the interval excludes 0) (n), or n/a for no interval or no mean.

    n_label goes before the count: "" gives "(8)" (the `pairs` and `repeats` tables), "n = "
    gives "(n = 8)" (the results page's controls)."""
    if iv is None or iv.mean is None:
        return "n/a"
    half = "n/a" if iv.half is None else format(iv.half, fmt)
    dag = "†" if iv.excludes_zero else ""
    return f"{format(iv.mean, '+' + fmt)} ± {half}{dag} ({n_label}{iv.n})"


def heterogeneity_text(h, test: bool = True) -> str:
    """A scene_heterogeneity result as text, n/a for None. test=True: the F-test in full,
    "F(df1, df2) = F, p = p" (`pairs --by-seed`); test=False: its p-value alone, "p = 0.123"
    ("p < 0.001" below that; the findings tables' "scenes differ" cell)."""
    if h is None:
        return "n/a"
    if not test:
        return "p < 0.001" if h.p < 0.001 else f"p = {h.p:.3f}"
    return f"F({h.df_between}, {h.df_within}) = {h.f:.2f}, p = {h.p:.3f}"
