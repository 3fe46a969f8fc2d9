"""The relations."""
