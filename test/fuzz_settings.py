"""Hypothesis settings of the fuzz tests (test_fuzz_*.py): small and deterministic in
``make test``, larger on demand.

* ``make test``: each fuzz test tries its own small number of cases, derandomized (the same
  cases on every run and every machine), no example database (nothing written to the tree).
* ``ROGER_FUZZ_EXAMPLES=N``: every fuzz test tries N cases instead (``bench/fuzz.py`` sets
  it); ``ROGER_FUZZ_SEED=S`` draws them at random from seed S instead of derandomized, so
  that a long run explores cases the suite never tries.

``pytest --hypothesis-show-statistics test/test_fuzz_*.py`` prints the cases tried per test.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from hypothesis import HealthCheck, seed, settings

EXAMPLES_ENV = "ROGER_FUZZ_EXAMPLES"
SEED_ENV = "ROGER_FUZZ_SEED"


def fuzz(examples: int) -> Callable[[Any], Any]:
    """Settings for one fuzz test: ``examples`` cases in the suite (or ``ROGER_FUZZ_EXAMPLES``).

    No deadline: the suite shares two cores with other tests, and a slow case is not a
    failure here (a hang is: the test would not end).
    """
    n = int(os.environ.get(EXAMPLES_ENV, "0") or 0) or examples
    chosen = os.environ.get(SEED_ENV, "")
    configured = settings(max_examples=n, derandomize=not chosen, database=None,
                          deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])

    def apply(test: Any) -> Any:
        test = configured(test)
        return seed(int(chosen))(test) if chosen else test
    return apply
