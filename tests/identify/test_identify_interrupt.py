"""Ctrl-C during the posterior sampling (issue 27 item 9): ``KeyboardInterrupt`` leaves
``sample_posterior`` as itself, and nothing is printed. Before, emcee's wrapper around the
log-probability printed "emcee: Exception while calling your likelihood function" and a traceback
for the interrupt, so ``hil certify`` interrupted in its identify stage showed a traceback."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hil.identify.posterior import sample_posterior


class _Gaussian:
    """A 2-D standard normal log-density in the shape ``sample_posterior`` expects; the ``interrupt_at``-th
    call raises KeyboardInterrupt (as Python does when SIGINT arrives inside it)."""

    ndim = 2
    names = ("a", "b")
    noise = "gaussian"
    lo = np.full(2, -10.0)
    hi = np.full(2, 10.0)

    def __init__(self, interrupt_at: int | None) -> None:
        self.calls = 0
        self.after_interrupt = 0
        self.interrupt_at = interrupt_at
        self.model = SimpleNamespace(has_sampling_transform=False, n_params=2, from_z=lambda z: z)

    def __call__(self, z):
        self.calls += 1
        if self.interrupt_at is not None and self.calls > self.interrupt_at:
            self.after_interrupt += 1
        if self.calls == self.interrupt_at:
            raise KeyboardInterrupt
        z = np.atleast_2d(z)
        return -0.5 * np.sum(z**2, axis=1)


def test_ctrl_c_inside_the_log_probability_leaves_quietly(capfd):
    target = _Gaussian(interrupt_at=5)
    with pytest.raises(KeyboardInterrupt):
        sample_posterior(target, np.zeros(2), seed=1, initial_steps=50, max_steps=200)
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err and "emcee" not in out + err, out + err
    # the rest of the chunk never called the model again (the held interrupt answered -inf)
    assert target.after_interrupt == 0


def test_an_uninterrupted_run_samples_as_before():
    res = sample_posterior(_Gaussian(None), np.zeros(2), seed=1, initial_steps=200, max_steps=4000)
    draws = res.samples
    assert draws.shape[1] == 2 and np.all(np.abs(draws.mean(axis=0)) < 0.2)
    assert np.all(np.abs(draws.std(axis=0) - 1.0) < 0.15)
