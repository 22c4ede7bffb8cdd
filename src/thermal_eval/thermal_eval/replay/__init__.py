"""Replaying recordings through adaptive models (virtual experiments), their summaries, the
probe-and-hold baseline beside them and the bag regression goldens."""
