"""The `semslam` sub-commands, one module each; ``semslam.cli`` assembles them into the app.

A command module imports only typer at the top (``semslam --help`` stays fast) and the work it
does inside the command function.
"""
