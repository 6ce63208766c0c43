"""A participant session: the paper's protocol for one person in the browser console (free driving,
calibration scenes, the fit in their words, six games with a questionnaire after each), and the
researcher's analysis of the sessions' folders.

* ``protocol``: the bookkeeping, without ROS (the plan, answers, the subject's record);
* ``phases``: the phases, each a graph of node processes (``phase_graph``);
* ``runner``: ``supersafe session --participant ID``, the phases in turn, resumable;
* ``fit_view``: the fit screen, in the participant's words and the researcher's;
* ``analysis``: ``supersafe session --analyse DIR...``.

The page and its server are the live console's (``supersafe_ros.console``).
"""
