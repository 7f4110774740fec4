"""Command line of haptics-train (filled in by the train/ issue)."""


def main() -> None:
    raise SystemExit("haptics-train: not built yet")
