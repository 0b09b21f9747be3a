"""The framework-free core of the drive-by sensing dispatch service (numpy / scipy / networkx only)."""
