"""The learned bias correction: network container and hash (model), C export (export), training (train)."""
