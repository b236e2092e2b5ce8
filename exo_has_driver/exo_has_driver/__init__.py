"""Hardware driver and safety watchdog (issues 4 and 6 fill it)."""
