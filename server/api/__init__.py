"""HTTP and websocket routes. Routes parse and authorise; services do the work."""
