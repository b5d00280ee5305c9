"""The ABB EGM controller twin (issue 26; docs/abb.md)."""
