"""Command-line entry points for offline jobs and demos."""
