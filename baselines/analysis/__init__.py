"""Command-line tools that read finished runs and compute references; nothing imports them."""
