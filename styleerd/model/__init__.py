"""Torch modules: the Style-ERD generator, its discriminator, classifiers, checkpoints."""
