"""Process-wide settings the library manages for its calls (threads), restored after them. No torch at import."""
