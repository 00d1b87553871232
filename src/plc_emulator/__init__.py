"""plc_emulator package."""
