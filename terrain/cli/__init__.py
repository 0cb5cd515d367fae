"""The ``craterscape`` command: its root, error policy, option types and ``terrain`` group."""
