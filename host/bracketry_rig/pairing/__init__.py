"""Pairing of both cameras' frames with the trigger's TRIGGER events, by trigger sequence number."""
