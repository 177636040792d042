"""Placeholder smoke demo (replaced by the full pipeline)."""
def main() -> None:
    print("smoke")
