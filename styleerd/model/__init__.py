"""The networks: torch modules (generator, discriminator, classifiers, checkpoints) and, without
torch, the configuration and the models on disk as inference reads them (``config``, ``stored``)."""
