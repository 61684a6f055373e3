"""`python -m toolkit` is the `toolkit` command."""

from toolkit.app.cli import main

main()
