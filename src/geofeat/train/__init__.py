"""Training GeoPatch on simulated sequences: patch dataset and training loop."""
