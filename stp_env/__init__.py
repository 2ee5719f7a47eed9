"""stp-env: provably safe multi-UAV sequential trajectory planning under wind and an adversarial intruder."""

__version__ = "0.1.0"
