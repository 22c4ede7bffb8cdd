"""The adaptive Gaussian process of the Swiss-type-lathe thesis and its GP building blocks."""
