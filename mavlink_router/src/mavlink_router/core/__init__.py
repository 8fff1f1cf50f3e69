"""The router's functional core: frames, routing, dedup, signing, configuration and the engine (pure)."""
