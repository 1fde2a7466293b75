"""The `map-consistency` command line tool."""
