"""References as data: one case's (`Reference`) and a batch's, as columns (`References`).
`rbstudy.physics.references` computes them; the pipeline and the archive carry them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.physics.analytic import REFERENCE_KINDS
from rbstudy.physics.metrics import UNCERTAIN_MEASURES

__all__ = ["Reference", "References", "NONE_CODE"]

_FIELDS = tuple(S.STATE_FIELDS)  # quaternion, omega_body, position, velocity
NONE_CODE = REFERENCE_KINDS.index("none")  # the code of a case without a reference


@dataclass(frozen=True)
class Reference:
    """A reference trajectory on T output times: quaternion (T, 4), omega_body (T, 3) rad/s,
    position and velocity (T, 3); ``name`` (one of the reference kinds of
    `rbstudy.physics.analytic`) says where it comes from. ``uncertainty``: for an integrated
    reference that a second, independent integration checked, how far that one lies from it
    per error measure (orientation rad, omega relative, nodes m; `_differences`), else
    empty. ``floor``: the float64 floor of a closed form (`_floors`), rad; NaN for an
    integrated reference."""

    name: str
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    uncertainty: dict = field(default_factory=dict)
    floor: float = math.nan


@dataclass(frozen=True)
class References:
    """The references of m scenes on T output times, as columns.

    code : (m,) int8, each one's kind as its index in
    `rbstudy.physics.analytic.REFERENCE_KINDS`. quaternion : (m, T, 4); omega_body,
    position, velocity : (m, T, 3), as in `Reference`. uncertainty : (m, 3) per
    `UNCERTAIN_MEASURES`, NaN where nothing checked the reference. floor : (m,) rad, the
    float64 floor of a closed-form reference (`_floors`), NaN for an integrated one.
    ``references[k]`` is the k-th as a `Reference`.
    """

    code: np.ndarray
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    uncertainty: np.ndarray
    floor: np.ndarray

    @classmethod
    def empty(cls, count: int, n_times: int) -> References:
        """``count`` references on ``n_times`` times, all "none" (NaN) until filled in."""
        return cls(
            code=np.full(count, NONE_CODE, dtype=np.int8),
            **{
                name: np.full(
                    (count, n_times, S.STATE_FIELDS[name].stop - S.STATE_FIELDS[name].start), np.nan
                )
                for name in _FIELDS
            },
            uncertainty=np.full((count, len(UNCERTAIN_MEASURES)), np.nan),
            floor=np.full(count, np.nan),
        )

    def __len__(self) -> int:
        return len(self.code)

    def __getitem__(self, k: int) -> Reference:
        """The k-th reference, a `Reference`."""
        uncertainty = self.uncertainty[k]
        checked = not np.all(np.isnan(uncertainty))
        return Reference(
            name=REFERENCE_KINDS[self.code[k]],
            **{name: getattr(self, name)[k] for name in _FIELDS},
            uncertainty=dict(zip(UNCERTAIN_MEASURES, uncertainty.tolist(), strict=True)) if checked else {},
            floor=float(self.floor[k]),
        )

    def put(self, k: int, reference: Reference) -> None:
        """Store ``reference`` (a `Reference`) as the k-th, in place."""
        self.code[k] = REFERENCE_KINDS.index(reference.name)
        for name in _FIELDS:
            getattr(self, name)[k] = getattr(reference, name)
        self.uncertainty[k] = [reference.uncertainty.get(m, np.nan) for m in UNCERTAIN_MEASURES]
        self.floor[k] = reference.floor

    @property
    def names(self) -> np.ndarray:
        """(m,) object array: each one's kind by name."""
        return np.array(REFERENCE_KINDS, dtype=object)[self.code]

    @classmethod
    def gather(cls, chunks: Sequence[References], places: np.ndarray) -> References:
        """The references at ``places`` (n, 2) (chunk, position) of ``chunks``, in order."""
        starts = np.cumsum([0] + [len(chunk) for chunk in chunks])
        flat = starts[places[:, 0]] + places[:, 1]
        return cls(
            **{
                name: np.concatenate([getattr(chunk, name) for chunk in chunks])[flat]
                for name in ("code", *_FIELDS, "uncertainty", "floor")
            }
        )
