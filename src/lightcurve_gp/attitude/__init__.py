"""attitude."""
