"""Bayesian fusion of an object landmark's class observations, with connectivity constraints.

For a landmark (by its global id) observed with likelihood vectors P(Z_t | X), t = 1..T,

    P(X | Z_1..T) ∝ P(X) · Π_t P(Z_t | X)                   (the paper's BAYS stage)

and with the pipe configurations seen at it (Table 2),

    P(X | Z_1..T, C) ∝ P(X | Z_1..T) · [X compatible with every C seen]   (SEM stage)

A configuration counts as seen once it makes up at least ``min_configuration_fraction`` (10 %) of
the configurations reported for the landmark. The paper's rule takes every configuration at face
value, so one wrong view (a pipe passing near an elbow counted as its third, a few per cent of an
object's views on the tank mission) would rule out the true class for good; a rare configuration is noise,
a real one recurs. With few views a single one still counts (1 of 1 is 100 %), as in the paper.

Accumulated in log space so that long sequences neither underflow nor lose resolution. If the
connectivity rules out every class the observations support (a wrong pipe association, an
unknown fitting), the constraint is dropped for that landmark rather than returning a zero
posterior, and :meth:`ClassFusion.conflict` reports it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from semslam.semantics.connectivity import ConnectivityTable, most_restrictive

_FLOOR = 1e-12  # a likelihood of exactly 0 would veto a class forever


@dataclass
class _Track:
    log_lik: np.ndarray
    n_obs: int = 0
    configurations: list[int] = field(default_factory=list)


class ClassFusion:
    """Class posteriors of object landmarks, keyed by global landmark id.

    ``classes=None`` (an estimator, which knows the classes only from the likelihoods it receives):
    the class set is open, a class enters with the first likelihood that names it, under a uniform
    prior, and the views fused before had likelihood 0 (floored) for it, as for any class a view does
    not name."""

    def __init__(
        self,
        classes: Sequence[str] | None,
        prior: Mapping[str, float] | None = None,
        connectivity: ConnectivityTable | None = None,
        min_configuration_fraction: float = 0.1,
    ):
        if not 0.0 <= min_configuration_fraction <= 1.0:
            raise ValueError("min_configuration_fraction must lie in [0, 1]")
        if classes is None and prior is not None:
            raise ValueError("a class prior needs the classes")
        self.min_configuration_fraction = float(min_configuration_fraction)
        self.open = classes is None
        self.classes = list(classes or ())
        p = np.ones(len(self.classes)) if prior is None else np.array([prior.get(c, 0.0) for c in self.classes])
        if self.open:
            p = np.ones(1)  # no class yet: the uniform prior's normalisation is irrelevant
        if np.any(p < 0) or p.sum() <= 0:
            raise ValueError("class prior must be non-negative with positive mass")
        self._closed_log_prior = np.log(np.maximum(p / p.sum(), _FLOOR))
        self.table = connectivity or ConnectivityTable()
        self._tracks: dict[Hashable, _Track] = {}
        # (landmark, use_connectivity) → (posterior, conflict), until the landmark's evidence or
        # the class set changes: a map is read far more often (every replay step) than it changes.
        self._cache: dict[tuple[Hashable, bool], tuple[np.ndarray, bool]] = {}
        self._masks: dict[tuple[int, frozenset], np.ndarray] = {}  # (how many classes, configurations seen)

    def _vector(self, likelihood: Mapping[str, float]) -> np.ndarray:
        unknown = [c for c in likelihood if c not in self.classes]
        if unknown and not self.open:
            raise KeyError(f"likelihood names unknown classes: {sorted(unknown)}")
        if unknown:
            self._cache.clear()
        for c in unknown:  # a new class: uniform prior, likelihood 0 (floored) in every earlier view
            self.classes.append(c)
            for tr in self._tracks.values():
                tr.log_lik = np.append(tr.log_lik, tr.n_obs * np.log(_FLOOR))
        v = np.array([likelihood.get(c, 0.0) for c in self.classes], dtype=np.float64)
        if np.any(v < 0) or not np.all(np.isfinite(v)):
            raise ValueError("likelihoods must be finite and non-negative")
        return v

    def update(
        self, landmark_id: Hashable, likelihood: Mapping[str, float] | None, configuration: int | None = None
    ) -> None:
        """Fuse one observation of ``landmark_id``: its class likelihood P(Z | X) (may be None when
        only the connectivity was observed) and the pipe configuration seen (1–4 or None)."""
        log_lik = np.log(np.maximum(self._vector(likelihood), _FLOOR)) if likelihood is not None else None
        self._forget_cached(landmark_id)
        tr = self._tracks.setdefault(landmark_id, _Track(np.zeros(len(self.classes))))
        if log_lik is not None:
            tr.log_lik = tr.log_lik + log_lik
            tr.n_obs += 1
        if configuration is not None:
            tr.configurations.append(int(configuration))

    def merge(self, keep: Hashable, drop: Hashable) -> None:
        """Two landmarks turned out to be one (the back-end merged them): pool their evidence."""
        if drop not in self._tracks:
            return
        self._forget_cached(keep)
        self._forget_cached(drop)
        d = self._tracks.pop(drop)
        tr = self._tracks.setdefault(keep, _Track(np.zeros(len(self.classes))))
        tr.log_lik = tr.log_lik + d.log_lik
        tr.n_obs += d.n_obs
        tr.configurations += d.configurations

    def forget(self, landmark_id: Hashable) -> None:
        """Drop a landmark's evidence (a tentative landmark that never entered the map)."""
        self._tracks.pop(landmark_id, None)
        self._forget_cached(landmark_id)

    def _forget_cached(self, landmark_id: Hashable) -> None:
        self._cache.pop((landmark_id, True), None)
        self._cache.pop((landmark_id, False), None)

    def _seen_configurations(self, tr: _Track) -> list[int]:
        """The configurations reported often enough to count (see the module)."""
        counts = Counter(tr.configurations)
        need = self.min_configuration_fraction * len(tr.configurations)
        return [c for c, n in counts.items() if n >= need]

    def _posterior(self, landmark_id: Hashable, use_connectivity: bool) -> tuple[np.ndarray, bool]:
        key = (landmark_id, use_connectivity)
        if key not in self._cache:
            self._cache[key] = self._compute_posterior(landmark_id, use_connectivity)
        return self._cache[key]

    def _compute_posterior(self, landmark_id: Hashable, use_connectivity: bool) -> tuple[np.ndarray, bool]:
        tr = self._tracks.get(landmark_id)
        if not self.classes:
            return np.zeros(0), False
        log_prior = np.zeros(len(self.classes)) if self.open else self._closed_log_prior
        log_post = log_prior + (tr.log_lik if tr else 0.0)
        post = np.exp(log_post - log_post.max())
        post /= post.sum()
        conflict = False
        if use_connectivity and tr and tr.configurations:
            masked = post * self._mask(self._seen_configurations(tr))
            if masked.sum() > 0:
                post = masked / masked.sum()
            else:
                conflict = True
        return post, conflict

    def _mask(self, seen: list[int]) -> np.ndarray:
        """The connectivity table's mask of the classes (classes are only ever appended: their
        number names the list) for the configurations ``seen``, made once per set of them."""
        key = (len(self.classes), frozenset(seen))
        if key not in self._masks:
            self._masks[key] = self.table.mask(self.classes, seen)
        return self._masks[key]

    def posterior(self, landmark_id: Hashable, use_connectivity: bool = True) -> dict[str, float]:
        """P(X | observations[, connectivity]) of a landmark; the prior if it was never observed."""
        post, _ = self._posterior(landmark_id, use_connectivity)
        return dict(zip(self.classes, post.tolist()))

    def map_class(self, landmark_id: Hashable, use_connectivity: bool = True) -> str:
        """The maximum-a-posteriori class of a landmark."""
        post, _ = self._posterior(landmark_id, use_connectivity)
        return self.classes[int(np.argmax(post))]

    def conflict(self, landmark_id: Hashable) -> bool:
        """True when the connectivity seen rules out every class and was therefore ignored."""
        return self._posterior(landmark_id, True)[1]

    def configuration(self, landmark_id: Hashable) -> int | None:
        tr = self._tracks.get(landmark_id)
        return most_restrictive(self._seen_configurations(tr)) if tr else None

    def n_observations(self, landmark_id: Hashable) -> int:
        tr = self._tracks.get(landmark_id)
        return tr.n_obs if tr else 0

    def landmarks(self) -> Iterable[Hashable]:
        return self._tracks.keys()

    def summary(self, landmark_id: Hashable) -> dict:
        """The semantic-map entry of a landmark: posterior, MAP class, evidence."""
        post = self.posterior(landmark_id)
        return {
            "posterior": post,
            "class": max(post, key=post.get),
            "n_observations": self.n_observations(landmark_id),
            "configuration": self.configuration(landmark_id),
            "connectivity_conflict": self.conflict(landmark_id),
        }


def fuse(
    likelihoods: Sequence[Mapping[str, float] | None],
    configurations: Iterable[int | None] = (),
    *,
    classes: Sequence[str] | None = None,
    connectivity: ConnectivityTable | None = None,
    prior: Mapping[str, float] | None = None,
) -> dict[str, float] | None:
    """Stateless fusion of one landmark's observations: the class posterior from its likelihood
    vectors P(Z | X) (None entries skipped) and the pipe configurations seen at it (SEM stage;
    pass no configurations for BAYS). ``classes`` default to the keys of the likelihoods in order
    of appearance; a class missing from a likelihood has likelihood 0 there (floored, see module).
    None when there is no likelihood at all."""
    liks = [lik for lik in likelihoods if lik]
    if not liks:
        return None
    if classes is None:
        classes = list(dict.fromkeys(k for lik in liks for k in lik))
    f = ClassFusion(classes, prior=prior, connectivity=connectivity)
    for lik in liks:
        f.update(0, lik)
    for c in configurations:
        f.update(0, None, c)
    return f.posterior(0)
