"""rawsim's command-line interface (installed as the ``rawsim_cli`` package)."""
