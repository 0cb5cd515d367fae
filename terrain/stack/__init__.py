"""Layer stacks: nested multi-resolution layers around a landing site, in memory or chunked."""
