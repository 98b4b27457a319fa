"""Changing layouts so that they stand: :mod:`.repair` (gradient-guided repair
and the baselines it is compared with)."""
