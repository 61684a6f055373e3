"""`python -m toolkit` is the `toolkit` command."""

from toolkit.app.entry import main

main()
