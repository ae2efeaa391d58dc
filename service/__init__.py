"""LiteGE service: REST and gRPC servers, shape store and batching over ``litege_core``.

Owns no maths. Kept import-light: ``python -m service.healthcheck`` loads it on every probe.
"""
