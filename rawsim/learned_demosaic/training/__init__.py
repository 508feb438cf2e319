"""How the ``learned`` demosaic's filters were fitted:
``python -m rawsim.learned_demosaic.training.train`` (see ``README.md`` here for the
photos, their sources, the command and the time it took)."""
