"""The supervisor console: a web page where a person watches the team and removes
obstacles (issue 8). ``state`` is the ROS-free model the page is drawn from,
``server`` the aiohttp web server, ``static/`` the page itself (no build step). The participant
protocol that runs on it is ``supersafe_ros.session``."""
