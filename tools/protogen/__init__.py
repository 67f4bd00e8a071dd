"""The protocol code generator, one module per output (tools/gen_protocol.py drives it)."""
