"""The technician's screen (`station ui`): a local web application for the whole alignment job.

app.py assembles it; guard.py and auth.py decide who may use it; hardware.py hands the cameras to
a step (runner.py, steps.py) or to the live view (live_feed.py) in turn; job.py keeps the job on
the lift; views.py turns results into what the pages show; routes_*.py answer each page's
requests; static/ holds the pages themselves. docs/ui.md describes the screen.
"""
