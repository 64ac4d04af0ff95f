"""Executes a Jupyter notebook end to end in its own folder (nbclient and
ipykernel) and fails on the first cell that raises: the example notebooks
run in CI (tests/it/python.rs). Usage: python scripts/run_notebook.py NOTEBOOK
"""

import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError


def main(path: Path) -> None:
    notebook = nbformat.read(path, as_version=4)
    clock = time.monotonic()
    client = NotebookClient(notebook, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}})
    try:
        client.execute()
    except CellExecutionError as e:
        sys.exit(f"{path}: a cell failed:\n{e}")
    cells = sum(1 for c in notebook.cells if c.cell_type == "code")
    figures = sum(1 for c in notebook.cells for o in c.get("outputs", []) if "image/png" in o.get("data", {}))
    print(f"ok: {path} ran {cells} code cells in {time.monotonic() - clock:.1f} s ({figures} figures)")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]))
