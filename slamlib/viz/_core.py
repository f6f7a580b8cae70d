"""Core plotting helpers (placeholder)."""

__all__: list[str] = []
