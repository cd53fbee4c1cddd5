"""The laser front-end."""
