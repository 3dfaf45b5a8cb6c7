"""``python -m warp_subdiv`` runs the command line."""
import sys

from .cli import main

if __name__ == "__main__":  # not when a Dask worker process (spawned) imports the main module again
    sys.exit(main())
