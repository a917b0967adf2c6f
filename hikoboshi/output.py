"""The consoles the command line prints through, and how its help is rendered.

On a terminal the consoles wrap at the terminal's width; when stdout (or stderr) is a pipe
or a file they do not hard-wrap: a line is as long as its content (up to ``PIPE_WIDTH``),
so that ``hikoboshi ... | grep`` and ``> file`` see whole lines. Help is rendered as
Markdown (``HELP_MARKUP``): Rich markup would eat bracketed names such as ``[limits]``, and
Markdown joins the lines of a wrapped docstring into one paragraph.
"""

from __future__ import annotations

from typing import Final, Literal

from rich.console import Console, ConsoleDimensions

__all__ = ["HELP_MARKUP", "PIPE_WIDTH", "PipeAwareConsole", "make_console"]

#: Typer's ``rich_markup_mode`` for every command group of the command line.
HELP_MARKUP: Final[Literal["markdown"]] = "markdown"

#: The width a console renders at when its stream is not a terminal (our choice: wide
#: enough for any line the commands print, bounded so that a full-width rule stays small).
PIPE_WIDTH: Final = 4096


class PipeAwareConsole(Console):
    """A Rich console that renders at ``PIPE_WIDTH`` columns when its stream is not a
    terminal (pipe, file, test runner) and at the terminal's width otherwise; an explicit
    ``width`` or ``COLUMNS`` still wins. The stream is looked at on each print, so a console
    made at import serves a terminal and a redirect alike."""

    @property
    def size(self) -> ConsoleDimensions:
        found = super().size
        if self._width is None and "COLUMNS" not in self._environ and not self.is_terminal:
            return ConsoleDimensions(PIPE_WIDTH, found.height)
        return found

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        self._width, self._height = new_size


def make_console(*, stderr: bool = False, soft_wrap: bool = False) -> Console:
    """A console for stdout (or stderr) that does not hard-wrap when piped."""
    return PipeAwareConsole(stderr=stderr, soft_wrap=soft_wrap)
