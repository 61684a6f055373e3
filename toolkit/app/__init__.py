"""The application: the `toolkit` command, fleet orchestration and the simulator's
native-format output. The only part of `toolkit` that uses `importers` and `reports`;
nothing else in the core imports it."""
