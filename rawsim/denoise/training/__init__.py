"""How the learned denoiser's weights were made: ``python -m rawsim.denoise.training.train``
(see ``README.md`` here for the images, their sources and licences, the seeds, the
profile mix, the command and the time it took)."""
