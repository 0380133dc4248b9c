"""The version of detcal: recorded in every profile it makes (``provenance.detcal_version``)."""

__version__ = "0.1.0"
