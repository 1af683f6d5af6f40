"""Calibration of the memory's noise model from the robot's own looks, without labels.

What the robot knows about its looks, and uses here:

* the looks of one spatial-map entry (one place, visited in one or several foci: after the
  attention shift, after a visual and after a haptic improvement) show one object: the
  spatial map associated them by position. Their differences are the robot's own measure
  of how much its features scatter for one object (``entry_scale``);
* looks of two different entries may show two copies of one category (seen from another
  place, so with other shading, distance and yaw) or two different categories. Which pairs
  are which is not known; a two-component mixture over the pairs' feature differences
  (expectation-maximisation, as in Fellegi-Sunter record linkage) separates them: a
  "same category" component, per feature a Gaussian core of scale sigma_f (with a small
  outlier share), against a "different" component, the empirical distribution of all
  differences between entries. Its sigma_f is the category-level spread of each feature
  (``feature_scale``), floored by ``entry_scale``.

Not every feature tells categories apart as well: each gets an information weight
``feature_weight``, the log of the ratio of how far looks of two entries lie apart
(``between_scale``, the spread of all between-entry differences) to how far two looks of
one category do (sigma_f): the nats of evidence for "same" that agreement in that feature
carries (the log-likelihood ratio at zero difference of two Gaussians of those scales).
A feature the robot measures no better than the world varies (S on plain objects) gets a
weight near 0 and no longer dilutes the distance. The weights are scaled to mean 1.

The acceptance distance is the ``identify_quantile`` of the robot's own repeat looks:
the weighted root-mean-square of the per-feature z-values, z_f = difference / (sqrt(2)
sigma_f), of same-entry pairs measured with their own scale; the same distance is then
applied with the category scale. The per-feature veto is the ``veto_quantile`` of one feature's
difference between two looks of one entry that agree on the other features (repeats the
robot accepts), scaled from the object's scatter to the category's, and at least the
``veto_quantile`` of the difference of two looks of one category under the category
scale (the noise model's own tail).

With a cap on each feature's |z| (the extended mode's robust distance), the cap itself is
measured too (``choose_z_cap``): the one whose acceptance distance takes in the fewest
looks of other map entries.

Pure numpy; no label is read. Labels (object, category) only score the result elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

#: Bins of the |difference| histogram of the "different" component.
_EDGES = np.concatenate([[0.0], np.geomspace(1e-3, 1.0, 40), [np.inf]])


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate` measured.

    Attributes:
        feature_scale: Per feature, the category-level spread sigma_f of one look.
        feature_weight: Per feature, the information weight of its z^2 in the distance:
            log(between_scale / feature_scale), >= 0, scaled to mean 1.
        between_scale: Per feature, the spread of one look among looks of different
            entries (MAD of their differences, Gaussian-consistent, / sqrt 2).
        entry_scale: Per feature, the spread of one look among the looks of one entry.
        identify_distance: RMS z-distance within which a look is taken for a repeat.
        noise_dof: Degrees of freedom of a multivariate Student-t whose RMS has the same
            ``identify_quantile`` as the robot's own repeat looks (their tail).
        veto: Per feature, the largest difference between two looks of one category: the
            ``veto_quantile`` of accepted repeats, scaled to the category spread, and at
            least that quantile of two looks' difference under the category scale.
        same_share: Share of the between-entry pairs the mixture calls same-category.
        pairs_same_entry: Number of same-entry pairs used.
        pairs_between: Number of between-entry pairs used.
        between_accepted: Share of the between-entry pairs (common known features >=
            ``min_common``) within the acceptance distance, measured with the category
            scale as the memory measures: how much of the rest of the world the radius
            that keeps ``identify_quantile`` of the robot's own repeats takes in (lower
            is better; ``choose_z_cap`` minimises it).
        flat_veto: Per feature, the veto between two looks the hand found smooth and flat
            (``flat_looks``) for the features of ``flat_vetoing``, NO_VETO for the rest
            (None when no look was marked flat): the larger of the robot's own
            ``veto_quantile`` difference between two such looks of one entry and the cap
            in a flat category's scale, z_cap sqrt 2 sigma_f, both measured on the flat
            looks alone (docs/memory.md, "The outline vetoes between flat tops").
        straight_veto: The same for two flat looks whose outline is straight
            (``straight_looks``: a box's top) and the features of ``straight_vetoing``,
            measured on those looks alone (None when none was marked; docs/memory.md,
            "The grey between two straight-edged tops").
        curved_veto: The same for two looks the hand found smooth and curved
            (``curved_looks``: a sphere) and the features of ``curved_vetoing``, measured
            on those looks alone (None when none was marked; docs/memory.md, "A sphere's
            albedo").
    """

    feature_scale: np.ndarray
    feature_weight: np.ndarray
    between_scale: np.ndarray
    entry_scale: np.ndarray
    identify_distance: float
    noise_dof: float
    veto: np.ndarray
    same_share: float
    pairs_same_entry: int
    pairs_between: int
    between_accepted: float = float("nan")
    flat_veto: np.ndarray | None = None
    straight_veto: np.ndarray | None = None
    curved_veto: np.ndarray | None = None


def flat_looks(features: np.ndarray, known: np.ndarray, crease_index: int,
               curvature_index: int, crease_max: float, curvature_max: float) -> np.ndarray:
    """Looks whose object the hand found smooth and flat-topped: crease (TC) and curvature
    (TK) both known, TC < ``crease_max`` and TK < ``curvature_max`` (a box's or cylinder's
    top; not a prism's ridge, not a sphere).

    Args:
        features: (n, F) looks.
        known: (n, F) their known masks.
        crease_index: Column of the crease feature (TC).
        curvature_index: Column of the curvature feature (TK).
        crease_max: Largest crease of a smooth top.
        curvature_max: Largest curvature of a flat top.

    Returns:
        (n,) bool.
    """
    x = np.asarray(features, np.float64)
    k = np.asarray(known, bool)
    return (k[:, crease_index] & k[:, curvature_index] & (x[:, crease_index] < crease_max)
            & (x[:, curvature_index] < curvature_max))


def curved_looks(features: np.ndarray, known: np.ndarray, crease_index: int,
                 curvature_index: int, crease_max: float, curvature_min: float) -> np.ndarray:
    """Looks whose object the hand found smooth and curved: crease (TC) and curvature (TK)
    both known, TC < ``crease_max`` and TK >= ``curvature_min`` (a sphere; not a flat top,
    not a prism's ridge).

    Returns:
        (n,) bool.
    """
    x = np.asarray(features, np.float64)
    k = np.asarray(known, bool)
    return (k[:, crease_index] & k[:, curvature_index] & (x[:, crease_index] < crease_max)
            & (x[:, curvature_index] >= curvature_min))


def straight_looks(features: np.ndarray, known: np.ndarray, flat: np.ndarray,
                   outline_index: int, outline_min: float) -> np.ndarray:
    """Flat looks (``flat_looks``) whose top outline is straight-edged: the outline (O)
    known and at least ``outline_min`` (a box's top departs from the rim's ellipse by
    about a straight edge's departure; a cylinder's is the ellipse).

    Returns:
        (n,) bool.
    """
    x = np.asarray(features, np.float64)
    k = np.asarray(known, bool)
    return np.asarray(flat, bool) & k[:, outline_index] & (x[:, outline_index] >= outline_min)


def two_class_split(values: np.ndarray) -> float:
    """The value that splits ``values`` into two classes with the largest variance
    between them (Otsu's threshold over the sorted values): midway between the two
    neighbouring values where the split falls.

    Raises:
        ValueError: Fewer than two distinct values.
    """
    v = np.sort(np.asarray(values, np.float64).ravel())
    if v.size < 2 or v[0] == v[-1]:
        raise ValueError(f"two_class_split: need two distinct values, got {v.size} values")
    n = np.arange(1, v.size)
    csum = np.cumsum(v)[:-1]
    low_mean = csum / n
    high_mean = (v.sum() - csum) / (v.size - n)
    between = n * (v.size - n) * (high_mean - low_mean) ** 2
    between[v[1:] == v[:-1]] = -1.0  # split only between two distinct values
    i = int(np.argmax(between))
    return float((v[i] + v[i + 1]) / 2.0)


def creased_looks(features: np.ndarray, known: np.ndarray, crease_index: int,
                  crease_min: float) -> np.ndarray:
    """Looks whose object the hand found creased: the crease (TC) known and at least
    ``crease_min`` (the touches crossed a prism's ridge or an edge).

    Returns:
        (n,) bool.
    """
    x = np.asarray(features, np.float64)
    k = np.asarray(known, bool)
    return k[:, crease_index] & (x[:, crease_index] >= crease_min)


def uncreased_common(common: np.ndarray, creased_a: np.ndarray, creased_b: np.ndarray,
                     unused: np.ndarray | None) -> np.ndarray:
    """The common-feature mask of pairs of looks with the features of ``unused`` left out
    where both looks of a pair are creased (``creased_looks``): a creased object's outline
    turns with its yaw, so between two of them it says nothing of the category
    (MemoryConfig.creased_unused).

    Args:
        common: (n, F) features known in both looks of each pair.
        creased_a, creased_b: (n,) whether each pair's first and second look is creased.
        unused: (F,) features to leave out between two creased looks (None: none).
    """
    if unused is None or not np.any(unused):
        return common
    both = np.asarray(creased_a, bool) & np.asarray(creased_b, bool)
    return common & ~(both[:, None] & np.asarray(unused, bool)[None, :])


def rms_z(delta: np.ndarray, common: np.ndarray, scale: np.ndarray,
          weight: np.ndarray | None = None, z_cap: float = 0.0) -> np.ndarray:
    """Weighted root-mean-square z over the common features:
    sqrt(sum_f w_f z_f^2 / sum_f w_f), z_f = delta_f / (sqrt(2) scale_f).

    Args:
        delta: (n, F) differences of two looks.
        common: (n, F) features known in both.
        scale: (F,) spread of one look.
        weight: (F,) weight of each feature (None: all 1, the plain RMS).
        z_cap: When > 0, each |z_f| counts at most this much (MemoryConfig.z_cap).

    Returns:
        (n,) distances; inf where no feature of positive weight is common.
    """
    w = np.ones(delta.shape[1]) if weight is None else np.asarray(weight, np.float64)
    cw = common * w
    z2 = (delta / (np.sqrt(2.0) * scale)) ** 2
    if z_cap > 0:
        z2 = np.minimum(z2, z_cap * z_cap)
    z2 = z2 * cw
    n = cw.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(z2.sum(axis=1) / np.where(n > 0, n, 1.0)), np.inf)


def information_weight(between_scale: np.ndarray, feature_scale: np.ndarray) -> np.ndarray:
    """log(between / feature scale) per feature, floored at 0, scaled to mean 1."""
    w = np.maximum(np.log(np.asarray(between_scale) / np.asarray(feature_scale)), 0.0)
    if not np.any(w > 0):
        return np.ones_like(w)
    return w / w.mean()


def _pairs(run: np.ndarray, entry: np.ndarray, same_entry: bool, max_pairs: int,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    parts_i, parts_j = [], []
    for r in np.unique(run):
        idx = np.flatnonzero(run == r)
        i, j = np.triu_indices(len(idx), 1)
        i, j = idx[i], idx[j]
        keep = (entry[i] == entry[j]) if same_entry else (entry[i] != entry[j])
        parts_i.append(i[keep])
        parts_j.append(j[keep])
    i, j = np.concatenate(parts_i), np.concatenate(parts_j)
    if len(i) > max_pairs:
        pick = np.sort(rng.choice(len(i), max_pairs, replace=False))
        i, j = i[pick], j[pick]
    return i, j


def _robust_scale(delta: np.ndarray, common: np.ndarray) -> np.ndarray:
    """Per feature, the spread of one look from pair differences (MAD, Gaussian-consistent)."""
    out = np.full(delta.shape[1], np.nan)
    for f in range(delta.shape[1]):
        d = np.abs(delta[common[:, f], f])
        if d.size >= 5:
            out[f] = 1.4826 * np.median(d) / np.sqrt(2.0)
    return out


def student_t_dof(distance: float, quantile: float, dims: int, seed: int = 0,
                  samples: int = 200_000) -> float:
    """Degrees of freedom nu of a ``dims``-variate Student-t (unit Gaussian scale) whose
    RMS over the dims has ``distance`` as its ``quantile``; 100 when even a Gaussian's
    quantile is as large (no heavier tail than a Gaussian's needed).

    Monte Carlo with a fixed seed: RMS^2 = (chi2_dims / dims) / (chi2_nu / nu).
    """
    num = np.random.default_rng(seed).chisquare(dims, samples) / dims

    def q(nu: float) -> float:
        den = np.random.default_rng(seed + 1).chisquare(nu, samples) / nu
        return float(np.sqrt(np.quantile(num / den, quantile)))

    lo, hi = 1.0, 100.0
    if q(hi) >= distance:
        return hi
    for _ in range(40):
        mid = np.sqrt(lo * hi)
        if q(mid) > distance:
            lo = mid
        else:
            hi = mid
    return float(np.sqrt(lo * hi))


def calibrate(features: np.ndarray, known: np.ndarray, run: np.ndarray, entry: np.ndarray,
              identify_quantile: float = 0.95, veto_quantile: float = 0.999,
              outlier_share: float = 0.02, iterations: int = 30, min_common: int = 6,
              max_pairs: int = 400_000, seed: int = 0, z_cap: float = 0.0,
              vetoing: np.ndarray | None = None, flat: np.ndarray | None = None,
              flat_vetoing: np.ndarray | None = None, creased: np.ndarray | None = None,
              creased_unused: np.ndarray | None = None, straight: np.ndarray | None = None,
              straight_vetoing: np.ndarray | None = None, curved: np.ndarray | None = None,
              curved_vetoing: np.ndarray | None = None) -> Calibration:
    """Measure the noise model from looks grouped by run and spatial-map entry.

    Args:
        features: (n, F) looks as sent to the memory (unknown entries ignored), F the
            feature mode's length.
        known: (n, F) their known masks.
        run: (n,) run of each look (pairs are formed within a run only: entry ids are
            per run).
        entry: (n,) spatial-map entry of each look.
        identify_quantile: Share of the robot's own repeat looks the acceptance distance
            keeps.
        veto_quantile: Quantile of one feature's difference between accepted repeat looks
            (scaled to the category spread) beyond which it is vetoed.
        outlier_share: Share of the same component's differences, per feature, allowed to
            be outliers (a bad look), drawn from the "different" distribution.
        iterations: EM iterations.
        min_common: Pairs with fewer common known features are not used for the distance.
        max_pairs: Pairs kept per kind (a seeded subsample beyond that).
        seed: Seed of the subsample.
        z_cap: The memory's cap of one feature's |z| (MemoryConfig.z_cap; 0: none): the
            acceptance distance and the veto's repeats are measured with the distance the
            memory will use.
        vetoing: (F,) features whose difference may veto (None: all). The others get
            NO_VETO: features that vary with the view (MemoryConfig docs, the extended
            mode's VIEW_DEPENDENT_FEATURES) differ between copies seen from two places by
            more than one object's looks from one place ever do.
        flat: (n,) looks whose object the hand found smooth and flat (``flat_looks``;
            None: none).
        flat_vetoing: (F,) features that veto between two flat looks
            (``Calibration.flat_veto``; None: none).
        creased: (n,) looks whose object the hand found creased (``creased_looks``;
            None: none).
        creased_unused: (F,) features left out of every pair of two creased looks, as
            the memory leaves them out (``uncreased_common``; None: none).
        straight: (n,) flat looks whose outline is straight (``straight_looks``; None:
            none).
        straight_vetoing: (F,) features that veto between two straight-edged flat looks
            (``Calibration.straight_veto``; None: none).
        curved: (n,) looks whose object the hand found smooth and curved
            (``curved_looks``; None: none).
        curved_vetoing: (F,) features that veto between two curved looks
            (``Calibration.curved_veto``; None: none).

    Returns:
        The Calibration.

    Raises:
        ValueError: Too few pairs of either kind to estimate a scale.
    """
    fit = _fit(features, known, run, entry, outlier_share, iterations, max_pairs, seed, flat,
               creased, creased_unused, straight, curved)
    return _finish(fit, identify_quantile, veto_quantile, min_common, seed, z_cap, vetoing,
                   flat_vetoing, straight_vetoing, curved_vetoing)


#: The veto of a feature that may not veto: every feature lies in [0, 1], so no
#: difference exceeds it.
NO_VETO: float = 1.0

#: The caps ``choose_z_cap`` tries (0: none).
Z_CAPS: tuple[float, ...] = (0.0, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 7.0, 8.0)


def choose_z_cap(features: np.ndarray, known: np.ndarray, run: np.ndarray,
                 entry: np.ndarray, caps: tuple[float, ...] = Z_CAPS,
                 identify_quantile: float = 0.95, veto_quantile: float = 0.999,
                 outlier_share: float = 0.02, iterations: int = 30, min_common: int = 6,
                 max_pairs: int = 400_000, seed: int = 0, vetoing: np.ndarray | None = None,
                 flat: np.ndarray | None = None, flat_vetoing: np.ndarray | None = None,
                 creased: np.ndarray | None = None, creased_unused: np.ndarray | None = None,
                 straight: np.ndarray | None = None,
                 straight_vetoing: np.ndarray | None = None,
                 curved: np.ndarray | None = None,
                 curved_vetoing: np.ndarray | None = None
                 ) -> tuple[Calibration, dict[float, float]]:
    """The cap of one feature's |z| chosen from the robot's own looks, and its calibration.

    A cap lets a copy through that differs from its category in one feature (a prism's
    outline at another yaw) and also squeezes every distance, other categories' too, into
    [0, cap]; the acceptance distance, the ``identify_quantile`` of the robot's own
    repeats, moves with it. Each cap is scored by the share of between-entry pairs (looks
    of two map entries: copies and other categories alike, no label read) that its
    acceptance distance takes in (``Calibration.between_accepted``), and the cap that
    takes in the fewest wins: at equal acceptance of the robot's own repeats, the one
    that tells most other looks apart.

    ``vetoing``, ``flat``, ``flat_vetoing``, ``creased``, ``creased_unused``, ``straight``,
    ``straight_vetoing``, ``curved`` and ``curved_vetoing`` as ``calibrate``'s.

    Returns:
        (the calibration with the chosen cap, {cap: between_accepted} for every cap).
    """
    fit = _fit(features, known, run, entry, outlier_share, iterations, max_pairs, seed, flat,
               creased, creased_unused, straight, curved)
    scores = {cap: _accepted(fit, _acceptance(fit, identify_quantile, min_common, cap),
                             min_common, cap)
              for cap in caps}
    best = min(scores, key=lambda cap: scores[cap])
    return (_finish(fit, identify_quantile, veto_quantile, min_common, seed, best, vetoing,
                    flat_vetoing, straight_vetoing, curved_vetoing), scores)


def _acceptance(fit: _Fit, identify_quantile: float, min_common: int, z_cap: float
                ) -> float:
    """The acceptance distance: the ``identify_quantile`` of the weighted RMS z of the
    robot's own repeats (same-entry pairs, z in their own scale)."""
    n_common = fit.c0.sum(axis=1)
    own = rms_z(fit.d0, fit.c0, fit.entry_scale, fit.weight, z_cap)[n_common >= min_common]
    return float(np.quantile(own, identify_quantile))


def _accepted(fit: _Fit, identify_distance: float, min_common: int, z_cap: float) -> float:
    """Share of the between-entry pairs within ``identify_distance`` (category scale)."""
    between = fit.c1.sum(axis=1) >= min_common
    return float(np.mean(rms_z(fit.d1[between], fit.c1[between], fit.scale, fit.weight,
                               z_cap) <= identify_distance))


@dataclass(frozen=True)
class _Fit:
    """What the cap-independent part of the calibration measured (pairs and scales)."""

    d0: np.ndarray
    c0: np.ndarray
    d1: np.ndarray
    c1: np.ndarray
    entry_scale: np.ndarray
    scale: np.ndarray
    between_scale: np.ndarray
    weight: np.ndarray
    share: float
    flat_fit: _Fit | None = None
    straight_fit: _Fit | None = None
    curved_fit: _Fit | None = None


def _fit(features: np.ndarray, known: np.ndarray, run: np.ndarray, entry: np.ndarray,
         outlier_share: float, iterations: int, max_pairs: int, seed: int,
         flat: np.ndarray | None = None, creased: np.ndarray | None = None,
         creased_unused: np.ndarray | None = None, straight: np.ndarray | None = None,
         curved: np.ndarray | None = None, partial: bool = False) -> _Fit:
    """The cap-independent part of ``calibrate``: the pairs, the look-to-look and category
    scales (the EM mixture), the between-entry scale and the information weights.

    ``partial`` (a sub-fit on some of the looks): a feature never known in two looks of
    one entry there (TR, a flat top's rim, on the curved looks of spheres) is left out of
    the fit (scales 1, weight 0) instead of raising."""
    x = np.asarray(features, np.float64)
    k = np.asarray(known, bool)
    if x.ndim != 2 or k.shape != x.shape:
        raise ValueError(f"features and known must be (n, F) alike, got {x.shape} and "
                         f"{k.shape}")
    n_feat = x.shape[1]
    run = np.asarray(run)
    entry = np.asarray(entry)
    rng = np.random.default_rng(seed)
    i0, j0 = _pairs(run, entry, True, max_pairs, rng)
    i1, j1 = _pairs(run, entry, False, max_pairs, rng)
    if len(i0) < 50 or len(i1) < 50:
        raise ValueError(f"too few pairs: {len(i0)} same-entry, {len(i1)} between entries")
    cr = np.zeros(len(x), bool) if creased is None else np.asarray(creased, bool)
    d0, c0 = x[i0] - x[j0], uncreased_common(k[i0] & k[j0], cr[i0], cr[j0], creased_unused)
    entry_scale = _robust_scale(d0, c0)
    never = ~np.isfinite(entry_scale)
    if never.any() and (not partial or never.all()):
        raise ValueError("some feature is never known in two looks of one entry")
    entry_scale = np.where(never, 1.0, np.maximum(entry_scale, 1e-4))

    d1, c1 = x[i1] - x[j1], uncreased_common(k[i1] & k[j1], cr[i1], cr[j1], creased_unused)
    c0, c1 = c0 & ~never, c1 & ~never
    a1 = np.abs(d1)
    feat = np.arange(n_feat)[None, :]
    bins = np.clip(np.searchsorted(_EDGES, a1, side="right") - 1, 0, len(_EDGES) - 2)
    dens = np.empty((n_feat, len(_EDGES) - 1))
    widths = np.diff(_EDGES)
    widths[-1] = 1.0
    for f in range(n_feat):
        h = np.bincount(bins[c1[:, f], f], minlength=len(_EDGES) - 1) + 0.5
        dens[f] = h / h.sum() / widths
    log_u = np.log(dens[feat, bins])
    scale = 2.0 * entry_scale
    share = 0.1
    log_eps, log_core = np.log(outlier_share), np.log(1.0 - outlier_share)
    for _ in range(iterations):
        s = np.sqrt(2.0) * scale
        log_g = np.log(2.0) - 0.5 * np.log(2 * np.pi) - np.log(s) - 0.5 * (d1 / s) ** 2
        log_m = np.logaddexp(log_core + log_g, log_eps + log_u)
        a = np.log(share) + (log_m * c1).sum(axis=1)
        b = np.log(1.0 - share) + (log_u * c1).sum(axis=1)
        resp = 1.0 / (1.0 + np.exp(np.clip(b - a, -50.0, 50.0)))
        share = float(np.clip(resp.mean(), 1e-3, 0.999))
        core = np.exp(log_core + log_g - log_m)
        w = resp[:, None] * core * c1
        total = np.where(never, 1.0, w.sum(axis=0))
        scale = np.maximum(np.sqrt((w * d1 ** 2).sum(axis=0) / (2.0 * total)), entry_scale)

    between_scale = np.where(never, 1.0, np.maximum(_robust_scale(d1, c1), 1e-4))
    weight = information_weight(between_scale, scale)
    # The same fit on the flat looks alone (how one flat top's features spread, and a flat
    # category's), on the straight-edged flat looks alone and on the curved ones.
    flat_fit, straight_fit, curved_fit = (
        _sub_fit(x, k, run, entry, mask, outlier_share, iterations, max_pairs, seed)
        for mask in (flat, straight, curved))
    return _Fit(d0, c0, d1, c1, entry_scale, scale, between_scale, weight, share, flat_fit,
                straight_fit, curved_fit)


def _sub_fit(x: np.ndarray, k: np.ndarray, run: np.ndarray, entry: np.ndarray,
             mask: np.ndarray | None, outlier_share: float, iterations: int, max_pairs: int,
             seed: int) -> _Fit | None:
    """``_fit`` on the looks of ``mask`` alone (None: no mask, or too few pairs)."""
    if mask is None:
        return None
    m = np.asarray(mask, bool)
    try:
        return _fit(x[m], k[m], run[m], entry[m], outlier_share, iterations, max_pairs, seed,
                    partial=True)
    except ValueError:
        return None


def _finish(fit: _Fit, identify_quantile: float, veto_quantile: float, min_common: int,
            seed: int, z_cap: float, vetoing: np.ndarray | None = None,
            flat_vetoing: np.ndarray | None = None,
            straight_vetoing: np.ndarray | None = None,
            curved_vetoing: np.ndarray | None = None) -> Calibration:
    """The part of ``calibrate`` that depends on the cap: acceptance distance, replay
    noise, veto and the share of other entries the acceptance takes in."""
    d0, c0, d1 = fit.d0, fit.c0, fit.d1
    entry_scale, scale, weight = fit.entry_scale, fit.scale, fit.weight
    n_feat = d0.shape[1]
    identify_distance = _acceptance(fit, identify_quantile, min_common, z_cap)
    # The Student-t of the replay noise: as many independent features as the weights
    # leave effective, (sum w)^2 / sum w^2 over all features.
    dims = max(1, int(round(weight.sum() ** 2 / (weight ** 2).sum())))
    dof = student_t_dof(identify_distance, identify_quantile, dims, seed)
    # The veto: per feature, the ``veto_quantile`` of its difference between two looks of
    # one entry that the robot itself accepts as repeats on the other features (weighted
    # RMS z within the acceptance distance, own scale): an entry that slid onto a neighbour
    # pairs two objects' looks and is left out by its other features (one such entry on
    # inspection set the weight's 99.9th percentile of all same-entry pairs to 0.14).
    # Scaled from one object's scatter to the category's (feature_scale / entry_scale):
    # another copy of the category, elsewhere, differs by that much more.
    # Floored at the ``veto_quantile`` of the difference of two looks of one category
    # under the noise model itself (a Gaussian of sqrt 2 sigma_f), as the curved veto is:
    # looks of one entry often share one measurement (every look of an object carries
    # its last weighing), so their differences understate the noise of two independent
    # ones, and a veto under that floor turns down more than 1 - ``veto_quantile`` of the
    # copies the distance takes (W: 0.040, 2.8 sigma of two weighings' difference).
    floor = NormalDist().inv_cdf(0.5 + veto_quantile / 2.0) * np.sqrt(2.0) * scale
    veto = np.empty(n_feat)
    for f in range(n_feat):
        others = c0.copy()
        others[:, f] = False
        repeat = ((others.sum(axis=1) >= min_common) & c0[:, f]
                  & (rms_z(d0, others, entry_scale, weight, z_cap) <= identify_distance))
        veto[f] = max(float(np.quantile(np.abs(d0[repeat, f]), veto_quantile)
                            * scale[f] / entry_scale[f]), float(floor[f]))
    if vetoing is not None:
        veto[~np.asarray(vetoing, bool)] = NO_VETO
    # Between two looks the hand found smooth and flat, the features of ``flat_vetoing``
    # veto at the larger of two things measured on the flat looks alone: the robot's own
    # largest difference between two looks of one entry (unscaled: a flat top's outline is
    # the same from every place) and the cap in a flat category's scale, beyond which the
    # distance no longer hears the feature.
    # The same between two straight-edged flat looks, and between two curved looks, on
    # those looks alone.
    flat_veto = _sub_veto(fit.flat_fit, flat_vetoing, n_feat, veto_quantile, z_cap)
    straight_veto = _sub_veto(fit.straight_fit, straight_vetoing, n_feat, veto_quantile, z_cap)
    # Between two curved looks the floor is not the cap: the distance weighs AS on the
    # scale of all looks (a box's AS moves with its yaw), so it never hears a sphere's
    # category spread; the floor is the veto quantile of two looks of one category under
    # that spread (sqrt 2 sigma_f), on the curved looks alone.
    curved_veto = _sub_veto(fit.curved_fit, curved_vetoing, n_feat, veto_quantile, z_cap,
                            cap_floor=False)
    accepted = _accepted(fit, identify_distance, min_common, z_cap)
    return Calibration(feature_scale=scale, feature_weight=weight,
                       between_scale=fit.between_scale, entry_scale=entry_scale,
                       identify_distance=identify_distance, noise_dof=dof, veto=veto,
                       same_share=fit.share,
                       pairs_same_entry=len(d0), pairs_between=len(d1),
                       between_accepted=accepted, flat_veto=flat_veto,
                       straight_veto=straight_veto, curved_veto=curved_veto)


def _sub_veto(sub: _Fit | None, vetoing: np.ndarray | None, n_feat: int,
              veto_quantile: float, z_cap: float, cap_floor: bool = True
              ) -> np.ndarray | None:
    """Per feature of ``vetoing``, the larger of the ``veto_quantile`` difference between
    two looks of one entry and a floor in the category scale sigma_f, both of the sub-fit's
    looks: the cap, z_cap sqrt 2 sigma_f (``cap_floor``), or else the ``veto_quantile``
    of the difference of two looks of one category, a Gaussian of sqrt 2 sigma_f; NO_VETO
    for the rest (None without a sub-fit or features)."""
    if sub is None or vetoing is None:
        return None
    z = z_cap if cap_floor else NormalDist().inv_cdf(0.5 + veto_quantile / 2.0)
    veto = np.full(n_feat, NO_VETO)
    for g in np.flatnonzero(np.asarray(vetoing, bool)):
        own = np.abs(sub.d0[sub.c0[:, g], g])
        tail = float(np.quantile(own, veto_quantile)) if own.size else NO_VETO
        veto[g] = min(NO_VETO, max(tail, z * np.sqrt(2.0) * sub.scale[g]))
    return veto
