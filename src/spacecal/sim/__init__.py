"""A seeded simulator of the paper's system: UR10 + NDI Polaris Vicra + 4-sphere marker."""
