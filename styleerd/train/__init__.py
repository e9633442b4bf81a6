"""Training: losses, the recognisers, and the resumable adversarial trainer."""
