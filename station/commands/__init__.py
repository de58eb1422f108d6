"""One module per `station` sub-command: each has add_arguments(parser) and run(args) -> int."""
