"""The field monitor: live previews, exposure statistics and the bracket advisor served to a browser."""
