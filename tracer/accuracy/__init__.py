"""A render's error: against a reference, estimated from independent parts, and spot checks."""
