"""A code editor from plain ipywidgets: a monospace Textarea beside a gutter of line numbers.

No maintained editor widget (Ace, CodeMirror, Monaco) installs from PyPI for ipywidgets 8 and
runs in Voila offline: ipyaceeditor and ipycodemirror do not exist there and ipymonaco (2020,
alpha) loads Monaco from a CDN.  So the editor is a Textarea styled as code, with a gutter
whose lines match the text's: the Textarea grows with the text instead of scrolling and does
not wrap lines, so line k of the gutter stays beside line k of the code.  A line can be marked
(an error's line).

Tab indents (Python needs indentation, a browser text box would move the focus): a few lines of
JavaScript (:data:`TAB_KEYS`), shown once through an Output widget (its outputs are trusted, in
JupyterLab and in Voila alike), listen for Tab on the page before the Textarea does: Tab inserts
spaces to the next multiple of 4, Tab or Shift-Tab on a selection indents or dedents its lines by
4, Shift-Tab dedents the line.  The edit goes through the browser's own text insertion, so it
can be undone (Ctrl-Z) and the Textarea sends the new text to the kernel as for typed keys.
"""

from __future__ import annotations

import html

import ipywidgets as widgets
from IPython.display import Javascript

__all__ = ["CodeEditor"]

FONT = "'DejaVu Sans Mono', 'Liberation Mono', Menlo, Consolas, monospace"
LINE = 18  # px per line, the same in the gutter and the text
PAD = 6  # px above the first line: the Textarea's border (1) and padding (5)

STYLE = f"""<style>
.pyfrep-code textarea {{
  font-family: {FONT}; font-size: 13px; line-height: {LINE}px; padding: {PAD - 1}px 8px;
  white-space: pre; overflow-wrap: normal; overflow-x: auto; overflow-y: hidden; tab-size: 4;
  resize: none; background: #fcfcfc; color: #1b1b1b;
}}
.pyfrep-gutter pre {{
  font-family: {FONT}; font-size: 13px; line-height: {LINE}px; margin: 0; padding: {PAD}px 6px 0 4px;
  text-align: right; color: #777; background: #eef0f2; min-width: 2.2em; user-select: none;
}}
.pyfrep-gutter .bad {{ background: #f4b8b8; color: #7a0000; font-weight: bold; }}
</style>"""

INDENT = 4
# one listener for the page, in the capture phase (ipywidgets' Textarea stops the key's propagation)
TAB_KEYS = f"""(function () {{
  if (window.pyfrepTabKeys) return;
  window.pyfrepTabKeys = true;
  const unit = " ".repeat({INDENT});
  const put = (t, a, b, text) => {{  // the browser's own insertion: undoable, fires "input"
    t.setSelectionRange(a, b);
    if (!document.execCommand("insertText", false, text)) {{
      t.setRangeText(text, a, b, "end");
      t.dispatchEvent(new Event("input", {{ bubbles: true }}));
    }}
  }};
  document.addEventListener("keydown", (e) => {{
    const t = e.target;
    if (e.key !== "Tab" || e.ctrlKey || e.altKey || e.metaKey || !t || t.tagName !== "TEXTAREA") return;
    if (!t.closest(".pyfrep-code")) return;
    e.preventDefault();
    e.stopPropagation();
    const v = t.value, s = t.selectionStart, end = t.selectionEnd;
    const first = v.lastIndexOf("\\n", s - 1) + 1;
    if (s === end && !e.shiftKey) {{  // spaces to the next multiple of {INDENT}
      put(t, s, s, " ".repeat({INDENT} - ((s - first) % {INDENT})));
      return;
    }}
    let last = end > s && v[end - 1] === "\\n" ? end - 1 : end;  // a selection ending at a line start
    const stop = v.indexOf("\\n", last);
    last = stop < 0 ? v.length : stop;
    const lines = v.slice(first, last).split("\\n");
    const moved = lines.map((l) => (e.shiftKey ? l.replace(/^ {{1,{INDENT}}}/, "") : unit + l));
    const text = moved.join("\\n");
    if (text === v.slice(first, last)) return;
    put(t, first, last, text);
    if (s === end) {{  // Shift-Tab without a selection: the caret stays on its text
      const at = Math.max(first, s - (lines[0].length - moved[0].length));
      t.setSelectionRange(at, at);
    }} else {{
      t.setSelectionRange(first, first + text.length);
    }}
  }}, true);
}})();"""


class CodeEditor(widgets.HBox):
    """A monospace text box with line numbers.

    Parameters
    ----------
    value : the initial code.
    min_rows : the box shows at least this many lines.
    width : CSS width of the text box.

    Attributes
    ----------
    text : the Textarea (``text.value`` is the code).   gutter : the line numbers (HTML).
    tab_keys : the Output that makes Tab and Shift-Tab indent and dedent (:data:`TAB_KEYS`).
    marked : the line marked (1-based), or None.

    Examples
    --------
    >>> editor = CodeEditor("a = 1\\nb = 2\\n")
    >>> editor.text.rows >= 3, editor.gutter.value.count("\\n") >= 2
    (True, True)
    >>> editor.mark(2)
    >>> "class='bad'>2<" in editor.gutter.value
    True
    >>> editor.value = "c = 3"  # an edit clears the mark
    >>> editor.marked is None
    True
    """

    def __init__(self, value: str = "", min_rows: int = 16, width: str = "640px"):
        self.min_rows = min_rows
        self.marked: int | None = None
        self.text = widgets.Textarea(value=value, layout=widgets.Layout(width=width), continuous_update=True)
        self.text.add_class("pyfrep-code")
        self.gutter = widgets.HTML()
        self.gutter.add_class("pyfrep-gutter")
        style = widgets.HTML(STYLE, layout=widgets.Layout(width="0px", height="0px", overflow="hidden"))
        self.tab_keys = widgets.Output(layout=widgets.Layout(width="0px", height="0px", overflow="hidden"))
        self.tab_keys.append_display_data(Javascript(TAB_KEYS))  # Tab indents (module docstring)
        super().__init__(
            [style, self.tab_keys, self.gutter, self.text], layout=widgets.Layout(align_items="flex-start")
        )
        self.text.observe(self._edited, names="value")
        self._edited()

    @property
    def value(self) -> str:
        """The code."""
        return self.text.value

    @value.setter
    def value(self, code: str) -> None:
        self.text.value = code

    def _lines(self) -> int:
        return self.text.value.count("\n") + 1

    def _edited(self, _: object = None) -> None:
        self.marked = None
        self.text.rows = max(self.min_rows, self._lines() + 1)  # grow: the gutter never scrolls apart
        self._draw()

    def mark(self, line: int | None) -> None:
        """Mark line ``line`` (1-based) in the gutter; None clears the mark."""
        self.marked = line
        self._draw()

    def _draw(self) -> None:
        numbers = [
            f"<span class='bad'>{k}</span>" if k == self.marked else html.escape(str(k))
            for k in range(1, self._lines() + 1)
        ]
        self.gutter.value = "<pre>" + "\n".join(numbers) + "</pre>"
