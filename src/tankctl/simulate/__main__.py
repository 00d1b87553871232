"""``python -m tankctl.simulate [docs/reproduction.md]``: regenerate the doc's generated blocks."""

from tankctl.simulate.markdown import regenerate_docs

if __name__ == "__main__":  # python -m tankctl.simulate [docs/reproduction.md]: refresh the doc
    import sys

    for item in regenerate_docs(sys.argv[1] if len(sys.argv) > 1 else "docs/reproduction.md"):
        print(f"regenerated {item}")
