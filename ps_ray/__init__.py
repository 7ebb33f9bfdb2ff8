"""ps_ray: Policy Stitching experiments as a Ray pipeline."""

__version__ = "0.1.0"
