"""A posterior over light directions on the upper hemisphere (DESIGN.md section 8).

The light search scores a set of directions (a near-uniform Fibonacci grid, each
standing for an equal share of the hemisphere's solid angle, plus finer points around
the best, each standing for its own smaller share). ``DirectionPosterior`` holds those
directions with their log-posterior values and the solid angle each stands for, and
answers what the renderer and the audit ask of it: the most probable direction, the
mean direction and the spread about it, the mass near a direction, the density at any
direction (a von Mises-Fisher kernel as wide as the grid's local spacing), and the rank
of a direction among the grid's.

Pure numpy; directions are unit (3,) vectors in the camera frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-12)


def log_integral(log_density, solid_angle) -> float:
    """log of the integral of ``exp(log_density)`` over directions each standing for
    ``solid_angle`` (sr): ``log_density`` (K,) may hold -inf (no mass); 0 where none is
    finite."""
    a = np.asarray(log_density, np.float64) + np.log(np.asarray(solid_angle, np.float64))
    a = a[np.isfinite(a)]
    if not len(a):
        return 0.0
    m = float(a.max())
    return m + math.log(float(np.exp(a - m).sum()))


def log_mixture(log_p, log_q, weight: float) -> np.ndarray:
    """(K,) ``log((1 - weight) exp(log_p) + weight exp(log_q))`` of two log densities
    (``log_q`` may be a number), ``weight`` in [0, 1); ``log_p`` itself where it is 0."""
    lp = np.asarray(log_p, np.float64)
    if weight <= 0.0:
        return lp
    return np.logaddexp(math.log1p(-weight) + lp, math.log(weight) + np.asarray(log_q, np.float64))


def with_misled(log_post, log_prior, solid_angle, misled: float) -> np.ndarray:
    """(K,) the log density of ``(1 - misled) p + misled q``: ``p`` the posterior
    ``exp(log_post)`` and ``q`` the prior ``exp(log_prior)``, each normalised over the
    directions (``solid_angle`` (K,) sr each); ``log_post`` itself where ``misled`` is 0.

    The likelihood of a photograph's shadows and shading is built on a model -- the
    depth mesh's casters, the lit level's basis, a white wall's bounce left out -- that
    is sometimes wrong for every pixel at once: then it is confidently wrong, and no
    temperature over its correlated pixels mends that without flattening the cases it
    gets right. ``misled`` is that chance, fitted with the temperature by the log score
    of the true direction over the generated calibration cases
    (``benchmarks/fit_light_constants.py``): the posterior keeps the prior's share, the
    direction the light takes when the cues mislead."""
    lp = np.asarray(log_post, np.float64)
    if misled <= 0.0:
        return lp
    q = np.asarray(log_prior, np.float64)
    return log_mixture(lp - log_integral(lp, solid_angle), q - log_integral(q, solid_angle), misled)


@dataclass(frozen=True)
class Mode:
    """One mode of a posterior (``DirectionPosterior.modes``): its mean ``direction``
    (3,), its densest grid direction ``peak`` (3,), the share of the posterior's mass it
    holds, and which of the posterior's directions it holds (``members``, (K,) bool)."""

    direction: np.ndarray
    peak: np.ndarray
    mass: float
    members: np.ndarray


@dataclass(frozen=True)
class DirectionPosterior:
    """``dirs`` (K, 3) unit directions; ``log_post`` (K,) unnormalised log-posterior
    *densities* (per steradian); ``solid_angle`` (K,) the solid angle (sr) each stands
    for. The probabilities are ``exp(log_post) * solid_angle``, normalised.
    ``loglik`` (K,) and ``log_prior`` (K,), when given, are what ``log_post`` was made
    of, so that another temperature can be tried (``tempered``) without scoring the
    directions again: the tempered posterior ``loglik / temperature + log_prior``,
    normalised, mixed with the prior, normalised, by ``misled`` (the chance that the
    likelihood misleads: ``with_misled``)."""

    dirs: np.ndarray
    log_post: np.ndarray
    solid_angle: np.ndarray
    loglik: np.ndarray | None = None
    log_prior: np.ndarray | None = None
    temperature: float = 1.0
    misled: float = 0.0

    @classmethod
    def from_parts(cls, dirs, loglik, log_prior, solid_angle, temperature: float,
                   misled: float = 0.0) -> "DirectionPosterior":
        """The posterior of ``loglik`` (K,) tempered by ``temperature`` under ``log_prior``
        (K,), mixed with the prior by ``misled`` in [0, 1) (``with_misled``)."""
        ll = np.asarray(loglik, np.float64)
        lp = np.asarray(log_prior, np.float64)
        if not 0.0 <= float(misled) < 1.0:
            raise ValueError(f"DirectionPosterior: misled must be in [0, 1), got {misled!r}")
        log_post = with_misled(ll / float(temperature) + lp, lp, solid_angle, float(misled))
        return cls(dirs=dirs, log_post=log_post, solid_angle=solid_angle, loglik=ll,
                   log_prior=lp, temperature=float(temperature), misled=float(misled))

    def tempered(self, temperature: float) -> "DirectionPosterior":
        """The same posterior at another temperature (needs ``loglik`` and ``log_prior``)."""
        if self.loglik is None or self.log_prior is None:
            raise ValueError("DirectionPosterior.tempered: made without its log-likelihood")
        return DirectionPosterior.from_parts(self.dirs, self.loglik, self.log_prior, self.solid_angle, temperature,
                                             self.misled)

    @property
    def informed(self) -> "DirectionPosterior":
        """The posterior the cues state where they do not mislead: this one without the
        prior's share ``misled`` (itself where that is 0 or no log-likelihood is kept)."""
        if self.misled <= 0.0 or self.loglik is None or self.log_prior is None:
            return self
        return DirectionPosterior.from_parts(self.dirs, self.loglik, self.log_prior, self.solid_angle,
                                             self.temperature)

    def __post_init__(self):
        d = np.asarray(self.dirs, np.float64).reshape(-1, 3)
        lp = np.asarray(self.log_post, np.float64).reshape(-1)
        om = np.asarray(self.solid_angle, np.float64).reshape(-1)
        if not (len(d) == len(lp) == len(om)) or len(d) == 0:
            raise ValueError("DirectionPosterior: dirs, log_post and solid_angle must be non-empty and of one length")
        if not np.all(np.isfinite(d)) or not np.all(om > 0):
            raise ValueError("DirectionPosterior: directions must be finite and solid angles positive")
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        lp = np.where(np.isfinite(lp), lp, -np.inf)
        if not np.isfinite(lp).any():  # nothing told apart: the prior's flat density
            lp = np.zeros_like(lp)
        object.__setattr__(self, "dirs", d)
        object.__setattr__(self, "log_post", lp)
        object.__setattr__(self, "solid_angle", om)

    # -- the distribution ----------------------------------------------------------------
    @property
    def probabilities(self) -> np.ndarray:
        """(K,) the mass each direction carries, summing to 1."""
        a = self.log_post + np.log(self.solid_angle)
        p = np.exp(a - a.max())
        return p / p.sum()

    @property
    def log_normaliser(self) -> float:
        """log of the integral of ``exp(log_post)`` over the hemisphere."""
        return log_integral(self.log_post, self.solid_angle)

    @property
    def map_direction(self) -> np.ndarray:
        return self.dirs[int(np.argmax(self.log_post))].copy()

    @property
    def mean_resultant(self) -> np.ndarray:
        """(3,) the probability-weighted mean of the directions (length <= 1: 1 when all
        the mass is at one direction)."""
        return self.probabilities @ self.dirs

    @property
    def mean_direction(self) -> np.ndarray:
        return _unit(self.mean_resultant)

    def rms_angle_deg(self, about=None) -> float:
        """The RMS angle (degrees) of the mass about ``about`` (default the mean direction)."""
        c = self.mean_direction if about is None else _unit(about)
        ang = np.arccos(np.clip(self.dirs @ c, -1.0, 1.0))
        return float(np.degrees(math.sqrt(float(self.probabilities @ ang ** 2))))

    def mass_within(self, direction, radius_deg: float) -> float:
        """The posterior mass within ``radius_deg`` of ``direction``."""
        c = math.cos(math.radians(radius_deg))
        return float(self.probabilities[self.dirs @ _unit(direction) >= c].sum())

    # -- the density at any direction ----------------------------------------------------------
    def _kappa(self) -> np.ndarray:
        """Per grid direction, a von Mises-Fisher concentration whose kernel covers the
        solid angle the direction stands for (kappa = 2 pi / solid angle: the kernel's
        mass within a cap of that area is about 1 - 1/e)."""
        return 2.0 * math.pi / self.solid_angle

    def log_density(self, direction) -> float:
        """The normalised posterior density (per steradian) at ``direction``: the grid's
        mass smoothed by each point's kernel (``_kappa``). Below the horizon of the grid
        it is the density of the nearest grid direction's kernel tail."""
        d = _unit(direction)
        k = self._kappa()
        # vMF density: k / (2 pi (1 - exp(-2k))) exp(k (cos - 1))
        logk = np.log(k) - math.log(2 * math.pi) - np.log1p(-np.exp(-2 * k)) + k * (self.dirs @ d - 1.0)
        a = np.log(np.maximum(self.probabilities, 1e-300)) + logk
        m = float(a.max())
        return m + math.log(float(np.exp(a - m).sum()))

    def rank(self, direction) -> int:
        """1 + the number of grid directions whose density is above the density at
        ``direction`` (1: no grid direction is more probable)."""
        ld = self.log_density(direction)
        grid = np.array([self.log_density(x) for x in self.dirs]) if len(self.dirs) <= 4096 else self.log_post
        return 1 + int((grid > ld + 1e-9).sum())

    def modes(self, max_modes: int, radius_deg: float, mass: float) -> list["Mode"]:
        """The posterior as at most ``max_modes`` lights (DESIGN.md section 8, "the
        posterior drawn"): the densest direction left and the mass within ``radius_deg``
        of it are a mode, at that mass's mean direction; then the densest direction left
        of the rest, and so on until the modes hold ``mass`` of the posterior. Each mode's
        ``mass`` is its share of the posterior (not renormalised: their sum is the share
        the modes stand for), heaviest first."""
        if int(max_modes) < 1 or not radius_deg > 0.0:
            raise ValueError(f"DirectionPosterior.modes: max_modes >= 1 and radius_deg > 0 (got {max_modes}, "
                             f"{radius_deg})")
        p = self.probabilities
        left = np.ones(len(p), bool)
        c = math.cos(math.radians(float(radius_deg)))
        out: list[Mode] = []
        while left.any() and len(out) < int(max_modes) and sum(m.mass for m in out) < float(mass):
            i = int(np.flatnonzero(left)[np.argmax(self.log_post[left])])
            inside = left & (self.dirs @ self.dirs[i] >= c)
            w = float(p[inside].sum())
            if not w > 0.0:
                break
            out.append(Mode(direction=_unit(p[inside] @ self.dirs[inside]), peak=self.dirs[i].copy(), mass=w,
                            members=inside))
            left &= ~inside
        return sorted(out, key=lambda m: -m.mass)

    def sun_sky_sh(self, where=None) -> np.ndarray:
        """(9,) the radiance SH (this posterior's frame) of a sun of unit strength spread
        over the posterior's mass at the directions ``where`` (a (K,) mask; None: all),
        in shading units: a sun of unit strength toward ``d`` shades a surface of normal
        ``n`` with ``max(0, n . d)``, which is the radiance ``pi delta(w - d)``, so a mass
        ``p_i`` at ``d_i`` adds ``pi p_i Y(d_i)``. Its shading is the expected shading
        of that mass's sun (up to the order-2 SH's smoothing)."""
        from zcomp_cli.scene import sh

        keep = np.ones(len(self.dirs), bool) if where is None else np.asarray(where, bool).reshape(-1)
        if len(keep) != len(self.dirs):
            raise ValueError(f"DirectionPosterior.sun_sky_sh: a mask of {len(self.dirs)} directions, got {len(keep)}")
        if not keep.any():
            return np.zeros(9)
        om = self.solid_angle[keep]
        return math.pi * sh.project(self.dirs[keep], self.probabilities[keep] / om, om)[:, 0]

    def to_info(self) -> dict:
        return {"map_direction": self.map_direction.tolist(), "mean_direction": self.mean_direction.tolist(),
                "mean_resultant_length": float(np.linalg.norm(self.mean_resultant)),
                "rms_angle_deg": self.rms_angle_deg(), "grid": int(len(self.dirs))}


def hemisphere_solid_angles(n: int) -> float:
    """The solid angle each of ``n`` equal-area directions of a hemisphere stands for."""
    return 2.0 * math.pi / max(int(n), 1)


__all__ = ["log_mixture", "with_misled", "DirectionPosterior", "Mode", "hemisphere_solid_angles"]
