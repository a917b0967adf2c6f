"""What crosses the link and what it means: wire schemas, codec, MCAP recording and the
post-pass analyses. Built by the link, server and analysis issues."""
