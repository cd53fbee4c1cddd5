"""The sonar front-end."""
