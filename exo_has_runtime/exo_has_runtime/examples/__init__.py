"""A two-node demonstration of the runtime: HAS commands out, HAS states back."""
