"""The oracle front-end."""
