"""What crosses the link and what it means: wire schemas, codec, MCAP recording and the
post-pass analyses."""
