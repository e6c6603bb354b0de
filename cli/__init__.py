"""The `springc` command-line application (installed as the package `springc_cli`)."""
