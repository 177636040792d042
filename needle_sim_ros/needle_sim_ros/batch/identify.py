"""``needle_batch identify``: tissue parameters fitted to all bags at once (nonlinear least squares).

Unknowns x_j = ln(p_j / p_j0); residuals: every bag's scaled signed residuals
(:func:`needle_sim_ros.batch.task.run_residuals`). ``scipy.optimize.least_squares`` (trust region reflective) with
forward-difference Jacobian columns (one offline run per bag and column) evaluated in parallel on the cluster.
Uncertainty: s^2 (J^T J)^-1 at the estimate, s^2 = |r|^2 / (m - n), mapped by dp = p dx.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
from scipy.optimize import least_squares

from needle_sim_ros.batch.cluster import map_ordered
from needle_sim_ros.batch.grid import GridError, ParameterSet, check_value
from needle_sim_ros.batch.task import ResidualScales, TaskSpec, error_line, run_residuals


class IdentifyError(RuntimeError):
    """The fit cannot go on (no usable bag, a bag failing mid-fit, residuals changing size)."""


@dataclass(frozen=True)
class FitParameter:
    """A fitted parameter (a node parameter or one element ``name[i]`` of an array) and its initial value."""

    node: str
    name: str
    initial: float

    @property
    def label(self) -> str:
        return f"{self.node}:{self.name}"


def parse_fit(text: str) -> FitParameter:
    """``[NODE:]NAME=INITIAL`` (node default ``needle_simulator``), e.g. ``tissue.layers.tip_stiffness[0]=9e3``."""
    target, equals, value = text.partition("=")
    node, _, name = target.rpartition(":")
    node = node or "needle_simulator"
    try:
        initial = float(value)
    except ValueError:
        initial = math.nan
    if not equals or not name or not (math.isfinite(initial) and initial > 0):
        raise GridError(f"--fit '{text}': expected [NODE:]PARAMETER=INITIAL with a positive initial value")
    check_value(node, name, initial)
    return FitParameter(node, name, initial)


def fitted_set(fits: list[FitParameter], values: Sequence[float]) -> ParameterSet:
    """The fitted parameters at ``values`` as per-node overrides."""
    result: ParameterSet = {}
    for fit, value in zip(fits, values):
        result.setdefault(fit.node, {})[fit.name] = float(value)
    return result


def residuals_or_error(spec: TaskSpec, scales: ResidualScales) -> np.ndarray | str:
    """On a worker: the bag's residuals, or the one-line reason they could not be computed."""
    try:
        return run_residuals(spec, scales)
    except Exception as error:  # noqa: BLE001 - reported per bag on the client
        return error_line(spec, error)


@dataclass
class Evaluation:
    """One point of the fit: parameters, cost 0.5 |r|^2 and per-bag RMS of the scaled residuals."""

    parameters: list[float]
    cost: float
    bag_rms: list[float]
    kind: str  # "residual" (the optimiser's point) or "jacobian" (a finite-difference column)


@dataclass
class FitResult:
    estimate: list[float]
    std: list[float]
    correlation: list[list[float]]
    cost: float
    residual_count: int
    evaluations: int
    success: bool
    message: str
    bags: list[str]
    dropped: dict[str, str]
    bag_rms_initial: list[float]
    bag_rms_final: list[float]
    history: list[Evaluation] = field(default_factory=list)


class Identification:
    """The objective over all bags, evaluated on the cluster (one task per bag and point, all at once)."""

    def __init__(self, client: Any, bags: list[TaskSpec], fits: list[FitParameter], scales: ResidualScales,
                 step: float = 0.01, quiet: bool = True) -> None:
        self.client, self.fits, self.scales, self.step, self.quiet = client, fits, scales, step, quiet
        self.bags = bags
        self.dropped: dict[str, str] = {}
        self.sizes: list[int] | None = None
        self.cache: dict[tuple[float, ...], list[np.ndarray]] = {}
        self.history: list[Evaluation] = []

    def parameters(self, x: np.ndarray) -> list[float]:
        return [f.initial * math.exp(v) for f, v in zip(self.fits, x)]

    def evaluate(self, points: list[np.ndarray], kind: str) -> list[list[np.ndarray]]:
        """Per point, the residual vectors of the bags; every (point, bag) run not cached goes out at once."""
        todo = [x for x in dict.fromkeys(tuple(map(float, x)) for x in points) if x not in self.cache]
        specs = [replace(bag, parameters=fitted_set(self.fits, self.parameters(x))) for x in todo for bag in self.bags]
        results = map_ordered(self.client, residuals_or_error, specs, self.scales, desc=f"identify ({kind})",
                              quiet=self.quiet, on_error=error_line)
        for k, x in enumerate(todo):
            per_bag = results[k * len(self.bags):(k + 1) * len(self.bags)]
            self._check(per_bag)
            self.cache[x] = per_bag
            cost = 0.5 * sum(float(r @ r) for r in per_bag)
            self.history.append(Evaluation(self.parameters(np.array(x)), cost,
                                           [float(np.sqrt(np.mean(r ** 2))) for r in per_bag], kind))
        return [self.cache[tuple(map(float, x))] for x in points]

    def _check(self, per_bag: list[np.ndarray | str]) -> None:
        for bag, result in zip(self.bags, per_bag):
            if isinstance(result, str):
                raise IdentifyError(f"bag '{bag.bag}' failed during the fit: {result}")
        sizes = [r.size for r in per_bag]
        if self.sizes is not None and sizes != self.sizes:
            raise IdentifyError(f"the residual counts changed during the fit ({self.sizes} -> {sizes}): a bag "
                                f"compared a different number of measurements; try other initial values")
        self.sizes = sizes

    def start(self) -> None:
        """Evaluate the initial point; bags that fail there are dropped (reported), the rest must succeed."""
        x0 = np.zeros(len(self.fits))
        specs = [replace(bag, parameters=fitted_set(self.fits, self.parameters(x0))) for bag in self.bags]
        results = map_ordered(self.client, residuals_or_error, specs, self.scales, desc="identify (start)",
                              quiet=self.quiet, on_error=error_line)
        self.dropped = {b.bag: r for b, r in zip(self.bags, results) if isinstance(r, str)}
        self.bags = [b for b, r in zip(self.bags, results) if not isinstance(r, str)]
        if not self.bags:
            raise IdentifyError("no bag could be evaluated at the initial parameters: "
                                + "; ".join(f"{b}: {m}" for b, m in self.dropped.items()))
        self.evaluate([x0], "residual")

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate(self.evaluate([x], "residual")[0])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Forward differences; the point and its n shifted copies are evaluated together on the cluster."""
        shifted = [x + self.step * e for e in np.eye(len(x))]
        base, *columns = (np.concatenate(r) for r in self.evaluate([x, *shifted], "jacobian"))
        return np.column_stack([(c - base) / self.step for c in columns])


def identify(client: Any, bags: list[TaskSpec], fits: list[FitParameter], scales: ResidualScales = ResidualScales(),
             step: float = 0.01, max_evaluations: int = 30, quiet: bool = True) -> FitResult:
    """Fit ``fits`` to all ``bags`` (their parameters are replaced by the fitted ones)."""
    problem = Identification(client, bags, fits, scales, step, quiet)
    problem.start()
    initial = problem.history[0].bag_rms
    fit = least_squares(problem.residuals, np.zeros(len(fits)), jac=problem.jacobian, method="trf",
                        x_scale=1.0, xtol=1e-4, ftol=1e-8, gtol=1e-8, max_nfev=max_evaluations)
    estimate = problem.parameters(fit.x)
    m, n = fit.fun.size, len(fits)
    covariance = np.full((n, n), np.nan)
    if m > n:
        s2 = float(fit.fun @ fit.fun) / (m - n)
        covariance = s2 * np.linalg.pinv(fit.jac.T @ fit.jac)
    std_x = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    correlation = covariance / np.outer(std_x, std_x) if np.all(std_x > 0) else np.full((n, n), np.nan)
    final = [float(np.sqrt(np.mean(r ** 2))) for r in problem.evaluate([fit.x], "residual")[0]]
    return FitResult(estimate, [float(p * s) for p, s in zip(estimate, std_x)], correlation.tolist(), float(fit.cost),
                     m, len(problem.history), bool(fit.success), str(fit.message), [b.bag for b in problem.bags],
                     problem.dropped, initial, final, problem.history)
