"""Thin commands of the `liquidgs` CLI; each module exposes main(argv) -> int."""
