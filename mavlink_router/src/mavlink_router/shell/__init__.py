"""The router's shells: pymavlink's message table, sockets and serial endpoints, the main loop, the tlog."""
