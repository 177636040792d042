"""A force contribution that breaks down at a given time, for the tests of failed steps."""
import numpy as np

from needle_sim_ros.model import ForceContribution, GeneralizedForce


class PoisonedAfter(ForceContribution):
    """No force until t_bad, NaN after it (a tissue law breaking down within a step)."""

    state_dependent, time_invariant, stateful = True, False, False

    def __init__(self, t_bad: float) -> None:
        self.t_bad = t_bad

    def evaluate(self, model, q, qd, t, base):
        return GeneralizedForce(np.full(model.n_dof, np.nan if t > self.t_bad else 0.0))
