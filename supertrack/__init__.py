"""supertrack package."""
