"""LiteGE service: the thin HTTP (and later gRPC) layer over ``litege_core``. Owns no maths."""
