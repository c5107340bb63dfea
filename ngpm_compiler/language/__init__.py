"""The .lsys language: grammar, parser, syntax nodes, built-in tables, checker, code generator."""
