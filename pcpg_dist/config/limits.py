"""Bounds shared by the stage configs: the largest seed, episode length and count pcpg accepts."""

MAX_SEED = 2**32 - 1  # NumPy's legacy seeding and torch.manual_seed both take any of these
MAX_EPISODE_STEPS = 100_000  # an episode cap; the paper's games need a few hundred at most
MAX_COUNT = 10_000_000  # episodes, epochs, trials: beyond this a run would take weeks
