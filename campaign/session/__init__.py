"""Sessions: the store and the only code that knows a session folder's files."""
