"""Default limits of trajectory validation (:mod:`bemlearn.data.validation`).

Plain numbers in a module that imports nothing, so that ``bemlearn data``'s parser can show them
without loading NumPy.
"""

__all__ = ["MIN_TRIAL_SAMPLES", "RATE_RTOL", "JITTER_RTOL"]

#: Default shortest accepted trial, samples (shorter ones are almost surely truncated recordings).
MIN_TRIAL_SAMPLES = 10
#: Default relative tolerance on each trial's median time step against 1 / sample_rate_hz.
RATE_RTOL = 1e-2
#: Default relative tolerance on every single time step against 1 / sample_rate_hz
#: (timestamp jitter: 10 % is 200 µs at 500 Hz, ten times what a real logger writes).
JITTER_RTOL = 0.1
