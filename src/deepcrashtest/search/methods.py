"""Search methods: the random reference experiment, the cross-entropy method, and a boundary scan.

Each method evaluates variants through an ``Evaluator`` and appends every simulated variant to a
``Log`` (parameters, outcome, method, iteration, simulation number) so that "simulations until
the first safe variant" is read off the log the same way for every method.

A variant is *safe* when it does not collide and its robustness (the minimum separation
distance, metres; <= 0 on collision) is above ``margin``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from deepcrashtest.search.evaluate import OUTCOME_FIELDS, Evaluator


@dataclass
class Log:
    """Every simulated variant in evaluation order."""

    theta: list[np.ndarray] = field(default_factory=list)
    outcome: dict[str, list[np.ndarray]] = field(default_factory=dict)
    method: list[str] = field(default_factory=list)
    iteration: list[int] = field(default_factory=list)

    def add(self, method: str, iteration: int, theta: np.ndarray, out: dict[str, np.ndarray]) -> None:
        self.theta.append(np.atleast_2d(theta))
        for k, v in out.items():
            self.outcome.setdefault(k, []).append(np.asarray(v))
        self.method += [method] * len(theta)
        self.iteration += [iteration] * len(theta)

    def arrays(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if not self.theta:
            return np.zeros((0, 0)), {k: np.zeros(0) for k in (*OUTCOME_FIELDS, "change")}
        return np.vstack(self.theta), {k: np.concatenate(v) for k, v in self.outcome.items()}

    def __len__(self) -> int:
        return len(self.method)


def is_safe(out: dict[str, np.ndarray], margin: float = 0.0) -> np.ndarray:
    """(B,) True where the variant avoids the collision with robustness above ``margin`` metres."""
    return ~np.asarray(out["collided"], bool) & (np.asarray(out["robustness"]) > margin)


def first_safe(out: dict[str, np.ndarray], methods: list[str], method: str, margin: float = 0.0) -> int | None:
    """1-based number of simulations ``method`` ran until (and including) its first safe variant."""
    mine = np.array([m == method for m in methods])
    safe = is_safe(out, margin)[mine]
    hits = np.flatnonzero(safe)
    return int(hits[0]) + 1 if hits.size else None


def score(out: dict[str, np.ndarray], margin: float = 0.0) -> np.ndarray:
    """Higher is better: safe variants rank by small change, all above unsafe ones ranked by robustness.

    Unsafe variants rank by robustness (the closer to safe, the better), ties among collisions
    broken by a later collision time.
    """
    rob = np.asarray(out["robustness"], dtype=float)
    ct = np.nan_to_num(np.asarray(out["collision_time"], dtype=float), nan=0.0, posinf=0.0)
    unsafe_score = rob + 1e-3 * ct
    safe_score = 1e6 - np.asarray(out["change"], dtype=float)
    return np.where(is_safe(out, margin), safe_score, unsafe_score)


# --------------------------------------------------------------------------- random
def random_search(
    ev: Evaluator, log: Log, rng: np.random.Generator, starts: int, noise_variants: int
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The reference experiment: ``starts`` x ``noise_variants`` variants, simulated at once."""
    theta = ev.space.reference_grid(rng, starts, noise_variants)
    out = ev(theta)
    log.add("random", 0, theta, out)
    return theta, out


# --------------------------------------------------------------------------- CEM
@dataclass(frozen=True)
class CemConfig:
    """Cross-entropy method settings (population per iteration, elites, smoothing, budget)."""

    population: int = 16
    elite_fraction: float = 0.25
    smoothing: float = 0.7  # weight of the new estimate in the mean/std update
    budget: int = 128  # simulations, including the line search
    line_search: int = 16  # simulations spent shrinking the best safe variant towards the original
    min_std: float = 0.02  # floor of each std, as a fraction of the parameter's natural spread
    margin: float = 0.0


def cem_search(ev: Evaluator, log: Log, rng: np.random.Generator, cfg: CemConfig) -> np.ndarray | None:
    """Adaptive search for the safe variant with the smallest change; returns its theta (or None).

    A diagonal Gaussian over theta starts at the original (mean 0) with the natural spread of
    each parameter (half box, noise sigma). Each iteration simulates ``population`` samples,
    keeps the best ``elite_fraction`` by ``score`` (first: closest to safe; once safe variants
    exist: the safe ones with the least change) and moves the Gaussian towards them. The last
    ``line_search`` simulations scale the best safe variant towards the original (theta * s,
    s in (0, 1]) to sit just on the safe side of the boundary.
    """
    space = ev.space
    scale = space.scale()
    mean = np.zeros(space.dim)
    std = scale.copy()
    best: np.ndarray | None = None
    best_change = np.inf
    used, it = 0, 0
    while True:
        # keep ``line_search`` simulations for the end once a safe variant exists
        n = min(cfg.population, cfg.budget - used - (cfg.line_search if best is not None else 0))
        if n < 2:
            break
        theta = space.clip(mean + std * rng.normal(size=(n, space.dim)))
        out = ev(theta)
        log.add("cem", it, theta, out)
        used += n
        safe = is_safe(out, cfg.margin)
        if safe.any():
            i = int(np.flatnonzero(safe)[np.argmin(out["change"][safe])])
            if out["change"][i] < best_change:
                best, best_change = theta[i].copy(), float(out["change"][i])
        elite = theta[np.argsort(-score(out, cfg.margin))[: max(2, int(round(n * cfg.elite_fraction)))]]
        mean = cfg.smoothing * elite.mean(axis=0) + (1 - cfg.smoothing) * mean
        std = cfg.smoothing * elite.std(axis=0) + (1 - cfg.smoothing) * std
        std = np.maximum(std, cfg.min_std * scale)
        it += 1
    if best is not None and cfg.budget - used > 0:
        best = _shrink(ev, log, best, cfg.budget - used, cfg.margin, it)
    return best


def _shrink(ev: Evaluator, log: Log, theta: np.ndarray, budget: int, margin: float, it: int) -> np.ndarray:
    """Scale a safe theta towards 0 on a grid, then once more inside the bracket; keep the smallest safe."""
    lo, hi = 0.0, 1.0
    n1 = max(1, budget // 2)
    best = theta
    for rnd, n in enumerate((n1, budget - n1)):
        if n < 1:
            continue
        s = np.linspace(lo, hi, n + 2)[1:-1]
        cand = s[:, None] * theta[None, :]
        out = ev(cand)
        log.add("cem", it + rnd, cand, out)
        safe = is_safe(out, margin)
        if safe.any():
            j = int(np.flatnonzero(safe)[0])  # smallest safe scale
            best = cand[j]
            hi = float(s[j])
            lo = float(s[j - 1]) if j > 0 else lo
        else:
            lo = float(s[-1])
    return best


# --------------------------------------------------------------------------- boundary
def boundary_scan(ev: Evaluator, log: Log, directions: int = 16, steps: int = 6, margin: float = 0.0) -> dict:
    """The safe/unsafe boundary in the start-offset plane (no path noise), by bisection along rays.

    For ``directions`` angles phi (0 = forward, counter-clockwise), finds the smallest start
    offset radius r (metres) at which the variant is safe, searching up to the box edge. All
    rays are simulated together, one batch per bisection step (``1 + steps`` batches).
    Returns ``{"angle_deg": [...], "radius_m": [...] (None: unsafe up to the box edge)}``.
    """
    space = ev.space
    phi = np.arange(directions) * 2 * np.pi / directions
    u = np.column_stack([np.cos(phi), np.sin(phi)])
    with np.errstate(divide="ignore"):
        r_edge = np.min(np.where(np.abs(u) > 1e-12, space.half_box / np.abs(u), np.inf), axis=1)

    def at(r: np.ndarray) -> np.ndarray:
        th = np.zeros((directions, space.dim))
        th[:, :2] = u * r[:, None]
        out = ev(th)
        log.add("boundary", int(at.calls), th, out)  # type: ignore[attr-defined]
        at.calls += 1  # type: ignore[attr-defined]
        return is_safe(out, margin)

    at.calls = 0  # type: ignore[attr-defined]
    found = at(r_edge)
    lo, hi = np.zeros(directions), r_edge.copy()
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        safe = at(mid)
        hi = np.where(safe, mid, hi)
        lo = np.where(safe, lo, mid)
    return {
        "angle_deg": [round(float(a), 2) for a in np.degrees(phi)],
        "radius_m": [round(float(h), 3) if f else None for h, f in zip(hi, found, strict=True)],
    }
