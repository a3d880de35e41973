"""``rls_soak``: load and soak as a benchmark (memory growth, CPU, pose latency, dropped inputs); docs/soak.md."""

from .cli import main

__all__ = ["main"]
