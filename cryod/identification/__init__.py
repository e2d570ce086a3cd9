"""Identification of the cryostat model from measured records (``cryod identify``)."""
