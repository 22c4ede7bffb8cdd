"""Noise models of a recorded channel beyond white readings (a wandering level), fitted to a
residual and used to judge a change of the twin by what the noise cannot explain."""
from thermal_twin.noise.level_noise import LevelNoise, change_noise, fit_level_noise, judged_sums, whiten

__all__ = ["LevelNoise", "change_noise", "fit_level_noise", "judged_sums", "whiten"]
