"""The demos: ``neforward demo`` (the node live over loopback DDS) and ``neforward table``."""
