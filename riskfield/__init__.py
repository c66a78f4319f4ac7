"""riskfield: semantic-risk distance fields and CBF safety filtering from one RGB camera."""

__version__ = "0.1.0"
