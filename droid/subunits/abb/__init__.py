"""The ABB arm driven through Externally Guided Motion (EGM; issue 26, thesis §7.3; docs/abb.md)."""
