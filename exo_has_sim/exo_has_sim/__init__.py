"""HAS plant model, simulation and diagnosis (issues 3-5 fill it)."""
